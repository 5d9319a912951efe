// Drives a running CNCjs server headless, over the socket.io API its own browser client uses.
//
//   node drive.js URL SECRET          (NODE_PATH: the folder CNCjs was installed into)
//
// stdin: one JSON request per line, {"id": N, "emit": [event, ...args]}; the server's
// callback, if any, comes back as {"id": N, "reply": [...]}. stdout: one JSON line per
// event the server pushes ({"event": name, "args": [...]}), "connected" first.
//
// The access token is what CNCjs's own login makes: a JWT signed with the `secret` of its
// settings file (~/.cncrc), passed as ?token=.
'use strict';

const readline = require('readline');
const jwt = require('jsonwebtoken');
const io = require('socket.io-client');

const [url, secret] = process.argv.slice(2);
const token = jwt.sign({ id: '', name: '' }, secret, { expiresIn: '1h' });
const socket = io.connect(url, { query: `token=${token}`, transports: ['websocket'] });

function say(obj) {
  process.stdout.write(`${JSON.stringify(obj)}\n`);
}

const EVENTS = [
  'serialport:open', 'serialport:close', 'serialport:error', 'serialport:read',
  'serialport:write', 'workflow:state', 'controller:state', 'controller:settings',
  'sender:status', 'gcode:load', 'serialport:list',
];
for (const name of EVENTS) {
  socket.on(name, (...args) => say({ event: name, args }));
}
socket.on('connect', () => say({ event: 'connected' }));
socket.on('error', (err) => say({ event: 'error', args: [String(err)] }));
socket.on('disconnect', (reason) => say({ event: 'disconnected', args: [reason] }));

readline.createInterface({ input: process.stdin }).on('line', (line) => {
  const request = JSON.parse(line);
  socket.emit(...request.emit, (...reply) => say({ id: request.id, reply }));
}).on('close', () => {
  socket.close();
  process.exit(0);
});
