// The operator panel's page: one stream of server-sent events in, one POST per press out.
// Plain JavaScript, no build step and no third-party code: the preview and the chart are
// drawn on canvases.
"use strict";

const WINDOW_S = 10; // seconds of arc voltage and height shown on the live chart
const MAX_POINTS = 2000;
const TELEMETRY_STALE_MS = 2000; // older than this, the input lights read "unknown"
const CONFIRM_MS = 5000; // a reset asks once more, for this long
const points = []; // telemetry, oldest first
let view = null; // the panel's live view (links, state, progress, controls enabled)
let path = null; // the program's toolpath (the sender's sender/path)
let labels = { states: {}, inputs: {}, locks: {}, params: {}, material_fields: {}, history: {} };
let lastTelemetryAt = 0;
let streamUp = false;
let needToken = false; // the panel answered 401: the token form is shown until a login
let editing = null; // the material number being edited, or "new"
const pending = { chart: false, preview: false };

// Read by the browser tests and handy in the console: what this page has received.
window.panelStats = {
  telemetry: 0, views: 0, draws: 0, previewDraws: 0, paths: 0, opened: performance.now(),
};
window.lastTelemetry = null;

const $ = (selector) => document.querySelector(selector);
const num = (value) => typeof value === "number" && Number.isFinite(value);
const fmt = (value, digits, unit) => (num(value) ? `${value.toFixed(digits)}${unit}` : "-");
const stateWords = (state) =>
  (state && (labels.states[state] || state.replace(/_/g, " ").replace(/^./, (c) => c.toUpperCase()))) || "-";
const lockWords = (locks) => (locks || []).map((lock) => labels.locks[lock] || lock).join(", ");

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
  try {
    labels = await (await fetch("/api/labels")).json();
  } catch (error) { /* the page still works with names */ }
  decorateHistoryHeaders();
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
    else if (kind === "view") {
      const moved = JSON.stringify((view || {}).progress) !== JSON.stringify(data.progress);
      view = data; window.panelView = data; window.panelStats.views += 1; render();
      if (moved) schedule("preview"); // the torch and the part done
    } else if (kind === "path") {
      path = data && Array.isArray(data.moves) ? data : null;
      window.panelStats.paths += 1;
      schedule("preview");
    } else if (kind === "cut") loadHistory();
  };
}

function onTelemetry(point) {
  window.panelStats.telemetry += 1;
  const wasOn = window.lastTelemetry && window.lastTelemetry.torch_on;
  window.lastTelemetry = point;
  lastTelemetryAt = performance.now();
  points.push(point);
  if (points.length > MAX_POINTS) points.splice(0, points.length - MAX_POINTS);
  readout(point);
  schedule("chart");
  if (!!point.torch_on !== !!wasOn) schedule("preview"); // the marker's colour
}

// Draw at most once a frame, whatever arrives.
function schedule(what) {
  if (pending[what]) return;
  pending[what] = true;
  requestAnimationFrame(() => {
    pending[what] = false;
    if (what === "chart") {
      if (!points.length) return;
      const last = points[points.length - 1].t;
      drawChart($("#chart"), points.filter((p) => p.t >= last - WINDOW_S), last - WINDOW_S, last,
        "height_mm", true);
      window.panelStats.draws += 1;
    } else {
      drawPreview($("#preview"));
      window.panelStats.previewDraws += 1;
    }
  });
}

// --- the view: links, banner, readouts, controls --------------------------------------------

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
  showState(state.state);
  $("#r-thc").textContent = state.thc_enabled ? "on" : "off";
  $("#r-override").textContent = fmt(state.height_override_mm, 1, " mm");
  // A fault, in red; a pause the operator made is none (the program's line says it).
  const programError = (v.progress && v.progress.error) || "";
  const error = state.error || (programError.endsWith("paused by the operator") ? "" : programError);
  $("#r-error").hidden = !error;
  $("#r-error").textContent = error ? `Fault: ${error}` : "";
  renderProgram(v.progress);

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
  const select = $("#material-select");
  const selectReason = streamUp ? controls.material_select : "the panel is disconnected";
  select.disabled = selectReason !== null;
  select.title = selectReason || "the material the next cut starts with (a program's G200 still wins)";
  renderParams(v);
  renderMaterials(v.materials);
  renderConsumables(state.consumables);
  renderLights();
  const at = v.progress && v.progress.paused_at;
  $("#paused-where").textContent = at
    ? `Torch at line ${at.line} (cut ${at.cut ?? "-"}), X ${at.x_mm} Y ${at.y_mm} mm: ` +
      `${at.behind_mm} mm of the cut behind, ${at.ahead_mm} mm of the program ahead, ` +
      `offset ${at.offset_mm[0]}, ${at.offset_mm[1]} mm`
    : "No program is paused.";
}

function showState(state) {
  const line = $("#r-state");
  line.textContent = stateWords(state);
  line.className = `state ${state || ""}`;
}

// The program's line: what it is doing, in words; the DRO's X, Y and feed.
function renderProgram(progress) {
  const status = $("#r-status");
  $("#r-program").textContent = progress ? progress.program || ""
    : path ? `${path.program} (the last program)` : "";
  let text = view && view.sender ? "No program." : "No sender online.";
  let kind = "";
  if (progress) {
    const where = `line ${progress.line} of ${progress.total_lines} · cut ${progress.cut} of ${progress.total_cuts}`;
    const byOperator = String(progress.error || "").endsWith("paused by the operator");
    if (progress.paused_at && byOperator) {
      text = `Paused at line ${progress.paused_at.line}, cut ${progress.paused_at.cut ?? "-"}: the torch is out. ` +
        "Cycle start resumes here (touch-off and pierce where the torch stands).";
      kind = "paused";
    } else if (progress.paused_at) {
      text = `Stopped at line ${progress.paused_at.line}${progress.error ? `: ${progress.error}` : ""}. ` +
        "Move along the path, then resume here or restart the cut.";
      kind = "error";
    } else if (progress.running && progress.operator_paused) {
      text = `Paused at ${where}: the torch is out. Cycle start resumes.`;
      kind = "paused";
    } else if (progress.running && progress.waiting_cycle_start) {
      text = `Waiting for cycle start (S1) · ${where}`;
      kind = "paused";
    } else if (progress.running) {
      text = `Running · ${where}`;
    } else if (progress.error) {
      text = `Ended: ${progress.error}`;
      kind = "error";
    } else if (progress.total_lines) {
      text = `Finished · ${progress.total_lines} lines, ${progress.total_cuts} cuts`;
    }
  }
  status.textContent = text;
  status.className = `status ${kind}`;
  const x = progress ? progress.x_mm : null;
  const y = progress ? progress.y_mm : null;
  $("#r-x").textContent = fmt(x, 2, "");
  $("#r-y").textContent = fmt(y, 2, "");
  if (progress && num(progress.feed_mm_min)) $("#r-feed").textContent = progress.feed_mm_min.toFixed(0);
}

function readout(point) {
  $("#r-volts").textContent = fmt(point.voltage_v, 1, "");
  $("#r-target").textContent = fmt(point.target_v, 1, "");
  $("#r-height").textContent = fmt(point.height_mm, 2, "");
  $("#r-height-note").textContent = num(point.height_mm) ? "" : " (not probed yet)";
  $("#r-z").textContent = fmt(point.z_mm, 2, "");
  const cutting = point.state === "cutting";
  $("#r-locks").textContent = !cutting ? "not cutting"
    : point.locks && point.locks.length ? `holding Z: ${lockWords(point.locks)}` : "following the arc";
  const progress = view && view.progress;
  if (!(progress && num(progress.feed_mm_min)) && num(point.xy_speed_mm_s)) {
    $("#r-feed").textContent = (point.xy_speed_mm_s * 60).toFixed(0);
  }
  if (point.state) showState(point.state);
  renderLights();
}

// Every board input as a light, and the torch; grey while no telemetry comes.
const ALARMS = new Set(["estop", "breakaway", "z_limit_min", "z_limit_max"]);
function renderLights() {
  const list = $("#lights");
  const names = Object.keys(labels.inputs).length ? Object.keys(labels.inputs)
    : ["torch_on", "arc_ok", "ohmic", "float", "breakaway", "estop", "z_limit_min", "z_limit_max", "thc_up", "thc_down"];
  const key = names.map((name) => labels.inputs[name] || name).join("|");
  if (list.dataset.key !== key) {
    list.dataset.key = key;
    list.innerHTML = names.map((name) =>
      `<li data-input="${name}">${escapeHtml(labels.inputs[name] || name)}</li>`).join("");
  }
  const point = window.lastTelemetry;
  const fresh = point && performance.now() - lastTelemetryAt < TELEMETRY_STALE_MS;
  for (const item of list.children) {
    const name = item.dataset.input;
    const on = fresh && (name === "torch_on" ? !!point.torch_on : !!(point.inputs || {})[name]);
    item.className = [on ? "on" : "", ALARMS.has(name) ? "alarm" : "", name === "torch_on" ? "torch" : "",
      fresh ? "" : "unknown"].join(" ").trim();
    item.title = fresh ? (on ? "on" : "off") : "no telemetry from the daemon";
  }
}

function renderParams(v) {
  const state = v.state || {};
  const rows = (v.params_shown || []).map((row) =>
    `<tr><th${row.hint ? ` title="${escapeHtml(row.hint)}"` : ""}>${escapeHtml(row.label)}</th>` +
    `<td>${escapeHtml(row.text)}</td></tr>`);
  if (state.g200_active !== undefined) {
    rows.unshift(`<tr><th>Set by</th><td>${state.g200_active ? "the program's G200" : "the material"}</td></tr>`);
  }
  const selected = v.materials ? v.materials.selected : null;
  if (selected !== null && selected !== undefined) {
    rows.push(`<tr><th>Material</th><td>${escapeHtml(materialName(selected))}</td></tr>`);
  }
  const html = rows.join("");
  if ($("#params tbody").dataset.html !== html) {
    $("#params tbody").dataset.html = html;
    $("#params tbody").innerHTML = html;
  }
}

function materialName(number) {
  const m = materialsList().find((item) => item.number === number);
  if (number === 0) return "0 · default (no material chosen)";
  return m && m.name ? `${number} · ${m.name}` : `${number}`;
}

function renderConsumables(consumables) {
  const c = consumables || {};
  $("#r-pierces").textContent = num(c.pierces) ? String(c.pierces) : "-";
  $("#r-arc-on").textContent = num(c.arc_on_s) ? duration(c.arc_on_s) : "-";
  $("#r-since").textContent = c.since ? new Date(c.since).toLocaleString() : "-";
}

function duration(seconds) {
  const s = Math.round(seconds);
  if (s < 60) return `${s} s`;
  if (s < 3600) return `${Math.floor(s / 60)} min ${String(s % 60).padStart(2, "0")} s`;
  return `${Math.floor(s / 3600)} h ${String(Math.floor((s % 3600) / 60)).padStart(2, "0")} min`;
}

// The arguments a button's press carries: paused motion's step and feed, a recovery offset
// (the new offset from the one in force), a jog's step.
function argsFor(button) {
  const name = button.dataset.control;
  const feed = Number($("#path-feed").value);
  if (name === "path_back" || name === "path_forward") {
    return { mm: Number($("#path-step").value), feed_mm_min: feed };
  }
  if (name === "jog_up" || name === "jog_down") return { mm: Number($("#jog-step").value) };
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

// --- controls -------------------------------------------------------------------------------

const controlWords = {
  material_select: "Material", material_set: "Material saved", material_delete: "Material deleted",
  consumables_reset: "Consumables reset", login: "Log in",
};

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

// What came back, in words: "Probe test: done (surface 12.30 mm)".
function showAnswer(answer, name) {
  const line = $("#answer");
  line.className = answer.ok ? "ok" : "error";
  if (!answer.ok) { line.textContent = answer.error; return; }
  const data = answer.data || {};
  const chosen = num(data.material) ? data.material : data.number;
  if (name === "material_select" && num(chosen)) {
    line.textContent = `Next cut's material: ${materialName(chosen)}`;
    return;
  }
  const units = [["_mm_min", " mm/min"], ["_mm_s", " mm/s"], ["_mm", " mm"], ["_ms", " ms"], ["_v", " V"], ["_s", " s"]];
  const figures = Object.entries(data).filter(([key, value]) => num(value) && key !== "number"
    && key !== "transaction").slice(0, 3).map(([key, value]) => {
    const [suffix, unit] = units.find(([end]) => key.endsWith(end)) || ["", ""];
    return `${key.slice(0, key.length - suffix.length).replace(/_/g, " ")} ${value}${unit}`;
  });
  const point = window.lastTelemetry;
  if (name === "probe_test" && !figures.length && point && num(point.z_mm) && num(point.height_mm)) {
    // The plate as just probed: the height above plate is measured from it from now on.
    figures.push(`plate at Z ${(point.z_mm - point.height_mm).toFixed(2)} mm`);
  }
  line.textContent = `${controlWords[name] || name}: done${figures.length ? ` (${figures.join(", ")})` : ""}`;
}

async function press(name, args = {}) {
  const answer = await post(`/api/control/${name}`, args, name);
  showAnswer(answer, name);
  return answer;
}

function bindControls() {
  for (const button of document.querySelectorAll("[data-control]")) {
    controlWords[button.dataset.control] = controlWords[button.dataset.control] || button.textContent.trim();
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
  $("#material-select").addEventListener("change", async (event) => {
    const answer = await press("material_select", { number: Number(event.target.value) });
    if (!answer.ok) render(); // back to the daemon's choice
  });
  // A reset asks once more: the first press arms it for CONFIRM_MS.
  const reset = $("#consumables-reset");
  const resetText = reset.textContent;
  let armed = null;
  reset.addEventListener("click", async () => {
    if (!armed) {
      reset.textContent = "Press again to reset the counters";
      reset.classList.add("confirm");
      armed = setTimeout(() => { armed = null; reset.textContent = resetText; reset.classList.remove("confirm"); }, CONFIRM_MS);
      return;
    }
    clearTimeout(armed);
    armed = null;
    reset.textContent = resetText;
    reset.classList.remove("confirm");
    await press("consumables_reset", {});
  });
  setInterval(renderLights, 1000); // the lights go grey when telemetry stops
}

// --- materials ------------------------------------------------------------------------------

function materialsList() {
  return (view && view.materials && view.materials.materials) || [];
}

function renderMaterials(materials) {
  const list = (materials && materials.materials) || [];
  const rows = list.map((m) => `<tr data-number="${m.number}">
      <td>${m.number}</td><td>${escapeHtml(String(m.name || ""))}</td><td>${fmt(m.cut_height, 2, " mm")}</td>
      <td>${m.cut_volts ? fmt(m.cut_volts, 1, " V") : "auto"}</td><td>${fmt(m.cut_speed, 0, " mm/min")}</td>
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
  // The selector: every material, the daemon's choice selected.
  const select = $("#material-select");
  const options = list.map((m) => `<option value="${m.number}">${escapeHtml(materialName(m.number))}</option>`).join("");
  if (select.dataset.html !== options) {
    select.dataset.html = options;
    select.innerHTML = options;
  }
  const selected = materials ? materials.selected : null;
  if (selected !== null && selected !== undefined && document.activeElement !== select) {
    select.value = String(selected);
  }
}

function fieldLabel(key) {
  const q = labels.material_fields[key];
  if (!q) return escapeHtml(key);
  return `${escapeHtml(q.label)}${q.unit ? ` (${escapeHtml(q.unit)})` : ""}`;
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
    const hint = labels.material_fields[key] && labels.material_fields[key].hint;
    const title = hint ? ` title="${escapeHtml(hint)}"` : "";
    if (typeof value === "boolean") {
      return `<label${title}>${fieldLabel(key)} <input name="${name}" type="checkbox" data-kind="bool" ${value ? "checked" : ""}></label>`;
    }
    const kind = typeof value === "number" ? "number" : "text";
    const shown = value === null || value === undefined ? "" : escapeHtml(String(value));
    const step = kind === "number" ? ' step="any"' : "";
    return `<label${title}>${fieldLabel(key)} <input name="${name}" type="${kind}"${step} data-kind="${kind}" value="${shown}"></label>`;
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

function decorateHistoryHeaders() {
  for (const th of document.querySelectorAll("#cut-list th[data-history]")) {
    const q = labels.history[th.dataset.history];
    if (q && q.hint) th.title = q.hint;
  }
}

async function loadHistory() {
  const response = await fetch("/api/cuts");
  const cuts = await response.json();
  const rows = cuts.slice().reverse().map((c) => `<tr data-cut="${c.number}">
      <td>${c.number}</td><td>${c.start_line ?? "-"}</td><td>${c.material ?? "-"}</td>
      <td>${fmt(c.arc_start_s, 2, "")}</td><td>${fmt(c.pierce_s, 2, "")}</td><td>${fmt(c.arc_on_s, 2, "")}</td>
      <td>${fmt(c.target_v, 1, "")}</td><td>${fmt(c.volts_rms_v, 2, "")}</td>
      <td class="dim">${fmt(c.height_rms_mm, 2, "")} / ${fmt(c.height_max_mm, 2, "")}</td>
      <td>${escapeHtml(lockWords(Object.keys(c.locks))) || "-"}</td><td>${escapeHtml(c.error) || "-"}</td>
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
  const zKey = trace.some((p) => num(p.height_mm)) ? "height_mm" : "z_mm";
  $("#cut-height-key").textContent = zKey === "height_mm" ? "height above plate (mm)" : "Z, machine (mm)";
  drawChart($("#cut-chart"), trace, start, Math.max(end, start + 0.5), zKey, false);
  $("#cut-caption").textContent = `Cut ${number}: line ${cut.start_line ?? "-"}, arc on ${fmt(cut.arc_on_s, 2, " s")}, ` +
    `${trace.length} points${cut.error ? `, ended by: ${cut.error}` : ""}`;
}

// --- canvases -------------------------------------------------------------------------------

// The canvas sized to its box at the screen's pixel ratio; a context drawing in CSS pixels.
function surface(canvas) {
  const ratio = window.devicePixelRatio || 1;
  if (!canvas.dataset.aspect) canvas.dataset.aspect = String(canvas.height / canvas.width);
  const width = canvas.clientWidth || canvas.width;
  const height = Math.round(width * Number(canvas.dataset.aspect)) || canvas.height;
  if (canvas.width !== Math.round(width * ratio) || canvas.height !== Math.round(height * ratio)) {
    canvas.width = Math.round(width * ratio);
    canvas.height = Math.round(height * ratio);
  }
  const g = canvas.getContext("2d");
  g.setTransform(ratio, 0, 0, ratio, 0, 0);
  g.clearRect(0, 0, width, height);
  return { g, width, height, ratio };
}

const colors = {};
const cssColor = (name) => {
  if (!(name in colors)) colors[name] = getComputedStyle(document.documentElement).getPropertyValue(name).trim();
  return colors[name];
};

// A round step for about `count` grid lines over `span`: 1, 2 or 5 times a power of ten.
function niceStep(span, count) {
  const raw = Math.max(span, 1e-9) / count;
  const power = 10 ** Math.floor(Math.log10(raw));
  return [1, 2, 5, 10].map((k) => k * power).find((step) => step >= raw);
}

// --- the program preview: the toolpath, the part done, the torch ------------------------------

function pathBounds(p) {
  if (Array.isArray(p.bounds) && p.bounds.length === 4 && p.bounds.every(num)) return p.bounds;
  const b = [Infinity, Infinity, -Infinity, -Infinity];
  for (const move of p.moves) {
    for (const [x, y] of move.points) {
      b[0] = Math.min(b[0], x); b[1] = Math.min(b[1], y); b[2] = Math.max(b[2], x); b[3] = Math.max(b[3], y);
    }
  }
  return b;
}

// Where the torch is on the program: its line, and its XY (the sender's progress; while
// paused after an error, where it stopped).
function torchPlace() {
  const progress = view && view.sender ? view.progress : null;
  if (!progress) return null;
  const at = progress.paused_at;
  const x = num(progress.x_mm) ? progress.x_mm : at && at.x_mm;
  const y = num(progress.y_mm) ? progress.y_mm : at && at.y_mm;
  const line = at ? at.line : progress.line;
  const finished = !progress.running && !at && !progress.error && progress.total_lines > 0
    && progress.line >= progress.total_lines;
  // The move the torch is on: the sender's index into the path's moves, else by its line.
  const segment = num(progress.segment) ? progress.segment : null;
  return { x, y, line: num(line) ? line : 0, segment, finished };
}

// The index after which the torch is on a polyline, and the point it projects to.
function project(points, x, y) {
  let best = { d: Infinity, i: 0, p: points[0] };
  for (let i = 0; i + 1 < points.length; i += 1) {
    const [x0, y0] = points[i];
    const [x1, y1] = points[i + 1];
    const dx = x1 - x0;
    const dy = y1 - y0;
    const len2 = dx * dx + dy * dy;
    const u = len2 > 0 ? Math.max(0, Math.min(1, ((x - x0) * dx + (y - y0) * dy) / len2)) : 0;
    const px = x0 + u * dx;
    const py = y0 + u * dy;
    const d = (px - x) ** 2 + (py - y) ** 2;
    if (d < best.d) best = { d, i, p: [px, py] };
  }
  return best;
}

function drawPreview(canvas) {
  const { g, width, height } = surface(canvas);
  window.panelPreview = null;
  if (!path || !path.moves.length) {
    g.fillStyle = cssColor("--dim");
    g.font = "16px system-ui";
    g.fillText("No program loaded: the preview shows the sender's program when it starts.", 20, 40);
    return;
  }
  const pad = 34;
  const [x0, y0, x1, y1] = pathBounds(path);
  const scale = Math.min((width - 2 * pad) / Math.max(x1 - x0, 1), (height - 2 * pad) / Math.max(y1 - y0, 1));
  // Centred, the Y axis up.
  const ox = pad + (width - 2 * pad - (x1 - x0) * scale) / 2;
  const oy = pad + (height - 2 * pad - (y1 - y0) * scale) / 2;
  const px = (x) => ox + (x - x0) * scale;
  const py = (y) => oy + (y1 - y) * scale;
  window.panelPreview = { toCanvas: (x, y) => [px(x), py(y)], moves: path.moves, program: path.program };

  // A millimetre grid with its labels.
  const step = niceStep(Math.max(x1 - x0, y1 - y0), 8);
  g.strokeStyle = "#23282e"; g.fillStyle = cssColor("--dim"); g.font = "11px system-ui"; g.lineWidth = 1;
  for (let gx = Math.ceil(x0 / step) * step; gx <= x1 + 1e-9; gx += step) {
    g.beginPath(); g.moveTo(px(gx), oy); g.lineTo(px(gx), py(y0)); g.stroke();
    g.fillText(`${+gx.toFixed(3)}`, px(gx) - 8, py(y0) + 14);
  }
  for (let gy = Math.ceil(y0 / step) * step; gy <= y1 + 1e-9; gy += step) {
    g.beginPath(); g.moveTo(ox, py(gy)); g.lineTo(px(x1), py(gy)); g.stroke();
    g.fillText(`${+gy.toFixed(3)}`, 2, py(gy) + 4);
  }
  g.fillText("X mm →", width - 56, height - 4);
  g.fillText("↑ Y mm", 2, 12);

  const place = torchPlace();
  const polyline = (pts) => {
    g.beginPath();
    pts.forEach(([x, y], i) => (i ? g.lineTo(px(x), py(y)) : g.moveTo(px(x), py(y))));
    g.stroke();
  };
  const style = (move, done) => {
    const rapid = move.cut === null || move.cut === undefined;
    g.setLineDash(rapid ? [5, 5] : []);
    g.lineWidth = rapid ? 1 : done ? 3 : 2;
    g.strokeStyle = rapid ? (done ? "#4a4f55" : cssColor("--rapid")) : cssColor(done ? "--done" : "--cut");
  };
  path.moves.forEach((move, index) => {
    if (!move.points || move.points.length < 2) return;
    const bySegment = place && place.segment !== null;
    const done = place && (place.finished || (bySegment ? index < place.segment : move.line < place.line));
    const current = place && !place.finished && num(place.x)
      && (bySegment ? index === place.segment : move.line === place.line);
    if (current) { // done up to where the torch is on it
      const { i, p } = project(move.points, place.x, place.y);
      style(move, true); polyline([...move.points.slice(0, i + 1), p]);
      style(move, false); polyline([p, ...move.points.slice(i + 1)]);
    } else {
      style(move, done); polyline(move.points);
    }
  });
  g.setLineDash([]);

  if (place && num(place.x) && num(place.y)) { // the torch: a ring and a cross, lit when on
    const lit = !!(window.lastTelemetry && window.lastTelemetry.torch_on);
    const cx = px(place.x);
    const cy = py(place.y);
    g.strokeStyle = lit ? cssColor("--torch") : cssColor("--torch-off");
    g.fillStyle = lit ? cssColor("--torch") : "transparent";
    g.lineWidth = 2;
    g.beginPath(); g.arc(cx, cy, 7, 0, 2 * Math.PI); g.stroke();
    if (lit) { g.globalAlpha = 0.5; g.fill(); g.globalAlpha = 1; }
    g.beginPath(); g.moveTo(cx - 13, cy); g.lineTo(cx + 13, cy); g.moveTo(cx, cy - 13); g.lineTo(cx, cy + 13); g.stroke();
  }
}

// --- the chart: voltage and target on the left axis (V), height on the right (mm), time (s) -----

function drawChart(canvas, series, t0, t1, zKey, relative) {
  const { g, width, height } = surface(canvas);
  const pad = { left: 50, right: 50, top: 18, bottom: 26 };
  const w = width - pad.left - pad.right;
  const h = height - pad.top - pad.bottom;
  const heights = series.map((p) => p[zKey]).filter(num);
  // With a target, the scale is the THC's: ±30 V around it, so a 1 V correction shows and
  // the open-circuit spike of an arc start is clipped; without one, whatever was measured.
  const targets = series.map((p) => p.target_v).filter(num);
  let vLow;
  let vHigh;
  if (targets.length) {
    const target = targets[targets.length - 1];
    vLow = target - 30; vHigh = target + 30;
  } else {
    const volts = series.map((p) => p.voltage_v).filter(num);
    vLow = Math.min(...volts, 100) - 10; vHigh = Math.max(...volts, 140) + 10;
  }
  const hHigh = Math.max(...heights, 5) * 1.2;
  const x = (t) => pad.left + ((t - t0) / Math.max(t1 - t0, 1e-6)) * w;
  const yV = (v) => pad.top + h - ((v - vLow) / (vHigh - vLow)) * h;
  const yH = (mm) => pad.top + h - (mm / hHigh) * h;

  g.fillStyle = cssColor("--lock"); // THC locks as shaded columns
  for (let i = 1; i < series.length; i += 1) {
    if ((series[i].locks || []).length || (typeof series[i].locks === "string" && series[i].locks)) {
      g.fillRect(x(series[i - 1].t), pad.top, Math.max(1, x(series[i].t) - x(series[i - 1].t)), h);
    }
  }
  g.strokeStyle = "#3c4043"; g.fillStyle = cssColor("--dim"); g.font = "11px system-ui"; g.lineWidth = 1;
  for (let k = 0; k <= 4; k += 1) {
    const y = pad.top + (h * k) / 4;
    g.beginPath(); g.moveTo(pad.left, y); g.lineTo(pad.left + w, y); g.stroke();
    g.fillText((vHigh - ((vHigh - vLow) * k) / 4).toFixed(0), 8, y + 4);
    g.fillText((hHigh - (hHigh * k) / 4).toFixed(1), pad.left + w + 8, y + 4);
  }
  g.fillText("V", 8, 11);
  g.fillText("mm", pad.left + w + 8, 11);
  // Time: seconds before now on the live chart, from the cut's start on a cut's.
  const step = niceStep(t1 - t0, 6);
  for (let s = 0; s <= t1 - t0 + 1e-9; s += step) {
    const t = relative ? t1 - s : t0 + s;
    const label = relative ? (s ? `−${+s.toFixed(2)}` : "0") : `${+s.toFixed(2)}`;
    g.beginPath(); g.moveTo(x(t), pad.top + h); g.lineTo(x(t), pad.top + h + 4); g.stroke();
    g.fillText(label, x(t) - 8, height - 8);
  }
  g.fillText("s", pad.left + w + 8, height - 8);
  g.save();
  g.beginPath(); g.rect(pad.left, pad.top, w, h); g.clip();
  const line = (key, scale, stroke) => {
    g.strokeStyle = cssColor(stroke); g.lineWidth = 2; g.beginPath();
    let drawing = false;
    for (const p of series) {
      const value = p[key];
      if (!num(value)) { drawing = false; continue; }
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
window.addEventListener("resize", () => { schedule("preview"); schedule("chart"); });
