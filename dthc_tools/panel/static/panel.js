// The operator panel's page: one stream of server-sent events in, one POST per press out.
// Plain JavaScript, no build step and no third-party code: the chart is drawn on a canvas.
"use strict";

const WINDOW_S = 10; // seconds of arc voltage and height shown on the live chart
const MAX_POINTS = 2000;
const points = []; // telemetry, oldest first
let view = null; // the panel's live view (links, state, progress, controls enabled)
let streamUp = false;
let needToken = false; // the panel answered 401: the token form is shown until a login
let editing = null; // the material number being edited, or "new"
let drawPending = false;

// Read by the browser tests and handy in the console: what this page has received.
window.panelStats = { telemetry: 0, views: 0, draws: 0, opened: performance.now() };

const $ = (selector) => document.querySelector(selector);
const fmt = (value, digits, unit) =>
  typeof value === "number" ? `${value.toFixed(digits)}${unit}` : "-";

// --- the stream -----------------------------------------------------------------------------

// The view first: a 401 asks for the token (the login POST answers a cookie, which the
// stream, the history and the controls then carry; an EventSource cannot send a header).
async function start() {
  let response;
  try {
    response = await fetch("/api/view");
  } catch (error) {
    setTimeout(start, 2000);
    return;
  }
  needToken = response.status === 401;
  render();
  if (needToken) { $("#token").focus(); return; }
  connect();
  loadHistory();
}

async function login(event) {
  event.preventDefault();
  const answer = await post("/api/login", { token: $("#token").value.trim() }, "login");
  $("#token").value = "";
  if (answer.ok) start();
  else showAnswer(answer, "login");
}

function connect() {
  const source = new EventSource("/events");
  source.onopen = () => { streamUp = true; render(); };
  source.onerror = () => {
    streamUp = false;
    render();
    // A network error is retried by the EventSource itself; a refusal (401: the token
    // changed, 503: too many pages) closes it: look again in a while.
    if (source.readyState === EventSource.CLOSED) setTimeout(start, 5000);
  };
  source.onmessage = (message) => {
    const { kind, data } = JSON.parse(message.data);
    if (kind === "telemetry") onTelemetry(data);
    else if (kind === "view") { view = data; window.panelStats.views += 1; render(); }
    else if (kind === "cut") loadHistory();
  };
}

function onTelemetry(point) {
  window.panelStats.telemetry += 1;
  window.lastTelemetry = point;
  points.push(point);
  if (points.length > MAX_POINTS) points.splice(0, points.length - MAX_POINTS);
  readout(point);
  if (!drawPending) {
    drawPending = true;
    requestAnimationFrame(() => {
      drawPending = false;
      const last = points[points.length - 1].t;
      drawChart($("#chart"), points.filter((p) => p.t >= last - WINDOW_S), last - WINDOW_S, last,
        "height_mm");
      window.panelStats.draws += 1;
    });
  }
}

// --- the view: links, banner, readout, controls ----------------------------------------------

function setLink(id, ok, text, idle = false) {
  const item = $(id);
  item.className = ok ? "ok" : idle ? "idle" : "bad";
  item.textContent = text;
}

function offlineReason() {
  if (needToken) return "This panel needs its token";
  if (!streamUp) return "Panel connection lost: reconnecting…";
  if (!view) return "Waiting for the panel…";
  if (!view.broker) return "Broker unreachable: controls are disabled";
  if (!view.daemon) return "Daemon offline: controls are disabled";
  if (view.board !== "online") return `Board ${view.board}: controls are disabled`;
  return "";
}

function render() {
  const v = view || {};
  setLink("#link-panel", streamUp, "panel");
  setLink("#link-broker", !!v.broker, "broker");
  setLink("#link-daemon", !!v.daemon, "daemon");
  setLink("#link-board", v.board === "online", `board: ${v.board || "?"}`);
  setLink("#link-sender", !!v.sender, v.sender ? "sender" : "no sender", true);
  const banner = offlineReason();
  $("#banner").hidden = !banner;
  $("#banner").textContent = banner;
  $("#token-form").hidden = !needToken;

  const state = v.state || {};
  $("#r-state").textContent = state.state || "-";
  $("#r-thc").textContent = state.thc_enabled ? "on" : "off";
  $("#r-override").textContent = fmt(state.height_override_mm, 1, " mm");
  $("#r-error").textContent = state.error || (v.progress && v.progress.error) || "-";
  const progress = v.progress;
  $("#r-program").textContent = progress ? progress.program || "-" : "no sender";
  $("#r-line").textContent = progress ? `${progress.line} / ${progress.total_lines}` : "-";
  $("#r-cut").textContent = progress
    ? `${progress.cut} / ${progress.total_cuts}${progress.waiting_cycle_start ? " · waiting for cycle start" : ""}${progress.operator_paused ? " · paused" : ""}`
    : "-";

  const controls = v.controls || {};
  for (const button of document.querySelectorAll("[data-control]")) {
    const reason = streamUp ? controls[button.dataset.control] : "the panel is disconnected";
    button.disabled = reason !== null && reason !== undefined ? true : !view;
    button.title = button.disabled ? reason || "" : "";
  }
  for (const button of document.querySelectorAll("[data-needs]")) {
    const reason = streamUp ? controls[button.dataset.needs] : "the panel is disconnected";
    button.disabled = reason !== null;
    button.title = reason || "";
  }
  renderParams(state);
  renderMaterials(v.materials);
  const at = progress && progress.paused_at;
  $("#paused-where").textContent = at
    ? `Torch at line ${at.line} (cut ${at.cut ?? "-"}), X${at.x_mm} Y${at.y_mm}: ` +
      `${at.behind_mm} mm of the cut behind, ${at.ahead_mm} mm of the program ahead, ` +
      `offset ${at.offset_mm[0]}, ${at.offset_mm[1]} mm`
    : "No program is paused.";
}

// The arguments a button's press carries: paused motion's step and feed, a recovery offset
// (the new offset from the one in force).
function argsFor(button) {
  const name = button.dataset.control;
  const feed = Number($("#path-feed").value);
  if (name === "path_back" || name === "path_forward") {
    return { mm: Number($("#path-step").value), feed_mm_min: feed };
  }
  if (name === "recovery_offset") {
    const at = (view && view.progress && view.progress.paused_at) || { offset_mm: [0, 0] };
    if (button.dataset.zero) return { x_mm: 0, y_mm: 0, feed_mm_min: feed };
    const round = (x) => Math.round(x * 1000) / 1000;
    return {
      x_mm: round(at.offset_mm[0] + Number(button.dataset.dx)),
      y_mm: round(at.offset_mm[1] + Number(button.dataset.dy)),
      feed_mm_min: feed,
    };
  }
  return {};
}

function readout(point) {
  $("#r-volts").textContent = fmt(point.voltage_v, 1, " V");
  $("#r-target").textContent = fmt(point.target_v, 1, " V");
  $("#r-height").textContent = fmt(point.height_mm, 2, " mm");
  $("#r-z").textContent = fmt(point.z_mm, 2, " mm");
  $("#r-locks").textContent = (point.locks || []).join(", ") || "none";
  if (point.state) $("#r-state").textContent = point.state;
}

function renderParams(state) {
  const rows = Object.entries(state.params || {}).map(
    ([key, value]) => `<tr><th>${escapeHtml(key)}</th><td>${escapeHtml(String(value))}</td></tr>`,
  );
  if (state.g200_active !== undefined) {
    rows.unshift(`<tr><th>source</th><td>${state.g200_active ? "G200" : "material / program"}</td></tr>`);
  }
  const selected = view && view.materials ? view.materials.selected : null;
  if (selected !== null && selected !== undefined) {
    rows.push(`<tr><th>material</th><td>${escapeHtml(String(selected))}</td></tr>`);
  }
  $("#params tbody").innerHTML = rows.join("");
}

// --- controls -------------------------------------------------------------------------------

async function post(path, args, name) {
  const headers = { "Content-Type": "application/json", "X-DTHC-Panel": "1" };
  try {
    const response = await fetch(path, {
      method: "POST", headers, body: JSON.stringify(args), credentials: "same-origin",
    });
    return await response.json();
  } catch (error) {
    return { ok: false, error: `${name}: the panel did not answer (${error})` };
  }
}

function showAnswer(answer, name) {
  const line = $("#answer");
  line.className = answer.ok ? "ok" : "error";
  line.textContent = answer.ok ? `${name.replace("_", " ")}: done` : answer.error;
}

async function press(name, args = {}) {
  const answer = await post(`/api/control/${name}`, args, name);
  showAnswer(answer, name);
  return answer;
}

function bindControls() {
  for (const button of document.querySelectorAll("[data-control]")) {
    button.addEventListener("click", () => press(button.dataset.control, argsFor(button)));
  }
  $("#token-form").addEventListener("submit", login);
  $("#material-add").addEventListener("click", () => editMaterial("new"));
  $("#material-cancel").addEventListener("click", () => { editing = null; $("#material-form").hidden = true; });
  $("#material-form").addEventListener("submit", saveMaterial);
  $("#material-delete").addEventListener("click", async () => {
    const number = Number($("#material-form").elements.number.value);
    const answer = await press("material_delete", { number });
    if (answer.ok) { editing = null; $("#material-form").hidden = true; }
  });
}

// --- materials ------------------------------------------------------------------------------

function materialsList() {
  return (view && view.materials && view.materials.materials) || [];
}

function renderMaterials(materials) {
  const rows = ((materials && materials.materials) || []).map((m) => `<tr data-number="${m.number}">
      <td>${m.number}</td><td>${escapeHtml(String(m.name || ""))}</td><td>${fmt(m.cut_height, 2, " mm")}</td>
      <td>${m.cut_volts ? fmt(m.cut_volts, 1, " V") : "auto"}</td><td>${fmt(m.cut_speed, 0, "")}</td>
      <td>${m.number > 0 && m.number < 1000000 ? `<button type="button" class="edit" data-number="${m.number}">Edit</button>` : ""}</td></tr>`);
  const body = $("#material-list tbody");
  const html = rows.join("");
  if (body.dataset.html !== html) { // keep focus and clicks: only redraw what changed
    body.dataset.html = html;
    body.innerHTML = html;
    for (const button of body.querySelectorAll("button.edit")) {
      button.addEventListener("click", () => editMaterial(Number(button.dataset.number)));
    }
  }
}

function editMaterial(number) {
  const list = materialsList();
  const base = number === "new" ? list.find((m) => m.number === 0) : list.find((m) => m.number === number);
  if (!base) return;
  editing = number;
  const form = $("#material-form");
  form.hidden = false;
  form.elements.number.value = number === "new" ? "" : number;
  form.elements.number.readOnly = number !== "new";
  $("#material-legend").textContent = number === "new" ? "New material" : `Material ${number}`;
  $("#material-delete").hidden = number === "new";
  const fields = Object.entries(base).filter(([key]) => key !== "number");
  $("#material-fields").innerHTML = fields.map(([key, value]) => {
    const name = escapeHtml(key);
    if (typeof value === "boolean") {
      return `<label>${name} <input name="${name}" type="checkbox" data-kind="bool" ${value ? "checked" : ""}></label>`;
    }
    const kind = typeof value === "number" ? "number" : "text";
    const shown = value === null || value === undefined ? "" : escapeHtml(String(value));
    const step = kind === "number" ? ' step="any"' : "";
    return `<label>${name} <input name="${name}" type="${kind}"${step} data-kind="${kind}" value="${shown}"></label>`;
  }).join("");
}

async function saveMaterial(event) {
  event.preventDefault();
  const form = $("#material-form");
  const args = { number: Number(form.elements.number.value) };
  for (const input of $("#material-fields").querySelectorAll("input")) {
    if (input.dataset.kind === "bool") args[input.name] = input.checked;
    else if (input.dataset.kind === "number") {
      if (input.value.trim() !== "") args[input.name] = Number(input.value);
    } else args[input.name] = input.value;
  }
  const answer = await press("material_set", args);
  if (answer.ok) { editing = null; form.hidden = true; }
}

// --- cut history ----------------------------------------------------------------------------

async function loadHistory() {
  const response = await fetch("/api/cuts");
  const cuts = await response.json();
  const rows = cuts.slice().reverse().map((c) => `<tr data-cut="${c.number}">
      <td>${c.number}</td><td>${c.start_line ?? "-"}</td><td>${c.material ?? "-"}</td>
      <td>${fmt(c.arc_start_s, 2, "")}</td><td>${fmt(c.pierce_s, 2, "")}</td><td>${fmt(c.arc_on_s, 2, "")}</td>
      <td>${fmt(c.target_v, 1, "")}</td><td>${fmt(c.height_rms_mm, 2, "")} / ${fmt(c.height_max_mm, 2, "")}</td>
      <td>${escapeHtml(Object.keys(c.locks).join(", ")) || "-"}</td><td>${escapeHtml(c.error) || "-"}</td>
      <td><button type="button" class="plot" data-cut="${c.number}">Plot</button>
          <a href="/api/cuts/${c.number}.csv" download>CSV</a></td></tr>`);
  $("#cut-list tbody").innerHTML = rows.join("");
  for (const button of document.querySelectorAll("#cut-list button.plot")) {
    button.addEventListener("click", () => plotCut(Number(button.dataset.cut)));
  }
}

async function plotCut(number) {
  const cut = await (await fetch(`/api/cuts/${number}`)).json();
  const trace = cut.trace.filter((p) => typeof p.t_s === "number" || typeof p.t === "number")
    .map((p) => ({ ...p, t: p.t ?? p.t_s }));
  $("#cut-figure").hidden = false;
  const start = trace.length ? trace[0].t : 0;
  const end = trace.length ? trace[trace.length - 1].t : 1;
  drawChart($("#cut-chart"), trace, start, Math.max(end, start + 0.5), "z_mm");
  $("#cut-caption").textContent = `Cut ${number}: line ${cut.start_line ?? "-"}, arc on ${fmt(cut.arc_on_s, 2, " s")}, ` +
    `${trace.length} points${cut.error ? `, ended by: ${cut.error}` : ""}`;
}

// --- the chart: voltage and target on the left axis, a Z series (mm) on the right ----------

function drawChart(canvas, series, t0, t1, zKey) {
  const ratio = window.devicePixelRatio || 1;
  const width = canvas.clientWidth || canvas.width;
  const height = Math.round(width * (canvas.height / canvas.width)) || canvas.height;
  if (canvas.width !== Math.round(width * ratio)) {
    canvas.width = Math.round(width * ratio);
    canvas.height = Math.round(height * ratio);
  }
  const g = canvas.getContext("2d");
  g.setTransform(ratio, 0, 0, ratio, 0, 0);
  g.clearRect(0, 0, width, height);
  const pad = { left: 46, right: 46, top: 10, bottom: 22 };
  const w = width - pad.left - pad.right;
  const h = height - pad.top - pad.bottom;
  const heights = series.map((p) => p[zKey]).filter((x) => typeof x === "number");
  // With a target, the scale is the THC's: ±30 V around it, so a 1 V correction shows and
  // the open-circuit spike of an arc start is clipped; without one, whatever was measured.
  const targets = series.map((p) => p.target_v).filter((x) => typeof x === "number");
  let vLow;
  let vHigh;
  if (targets.length) {
    const target = targets[targets.length - 1];
    vLow = target - 30; vHigh = target + 30;
  } else {
    const volts = series.map((p) => p.voltage_v).filter((x) => typeof x === "number");
    vLow = Math.min(...volts, 100) - 10; vHigh = Math.max(...volts, 140) + 10;
  }
  const hHigh = Math.max(...heights, 5) * 1.2;
  const x = (t) => pad.left + ((t - t0) / Math.max(t1 - t0, 1e-6)) * w;
  const yV = (v) => pad.top + h - ((v - vLow) / (vHigh - vLow)) * h;
  const yH = (mm) => pad.top + h - (mm / hHigh) * h;
  const css = getComputedStyle(document.documentElement);
  const color = (name) => css.getPropertyValue(name).trim();

  g.fillStyle = color("--lock"); // THC locks as shaded columns
  for (let i = 1; i < series.length; i += 1) {
    if ((series[i].locks || []).length || (typeof series[i].locks === "string" && series[i].locks)) {
      g.fillRect(x(series[i - 1].t), pad.top, Math.max(1, x(series[i].t) - x(series[i - 1].t)), h);
    }
  }
  g.strokeStyle = "#3c4043"; g.fillStyle = color("--dim"); g.font = "11px system-ui"; g.lineWidth = 1;
  for (let k = 0; k <= 4; k += 1) {
    const y = pad.top + (h * k) / 4;
    g.beginPath(); g.moveTo(pad.left, y); g.lineTo(pad.left + w, y); g.stroke();
    g.fillText((vHigh - ((vHigh - vLow) * k) / 4).toFixed(0), 4, y + 4);
    g.fillText((hHigh - (hHigh * k) / 4).toFixed(1), pad.left + w + 6, y + 4);
  }
  g.fillText(`${(t1 - t0).toFixed(1)} s`, pad.left + w - 30, height - 6);
  g.save();
  g.beginPath(); g.rect(pad.left, pad.top, w, h); g.clip();
  const line = (key, scale, stroke) => {
    g.strokeStyle = color(stroke); g.lineWidth = 2; g.beginPath();
    let drawing = false;
    for (const p of series) {
      const value = p[key];
      if (typeof value !== "number") { drawing = false; continue; }
      if (drawing) g.lineTo(x(p.t), scale(value)); else g.moveTo(x(p.t), scale(value));
      drawing = true;
    }
    g.stroke();
  };
  line("voltage_v", yV, "--volts");
  line("target_v", yV, "--target");
  line(zKey, yH, "--height");
  g.restore();
}

function escapeHtml(text) {
  return text.replace(/[&<>"']/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;" })[c]);
}

bindControls();
render();
start();
