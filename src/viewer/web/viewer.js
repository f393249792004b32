// pp5echo's live viewer: draws what the host streams over one WebSocket and
// sends the user's changes back as JSON control messages (docs/protocol.md,
// "The viewer's protocol"). Plain JavaScript, no build step, no network
// beyond the page's own server.
'use strict';

const $ = (id) => document.getElementById(id);

// What the page has seen, for people (the figures) and for the browser test.
const pp5 = window.pp5 = {
  connected: false, images: 0, distinct: new Set() /* hashes of different images, at most 4096: the first seen goes first */, lastImage: null, epoch: -1,
  latencies: [], latencyParts: [], shownTimes: [], viewResponses: [], errors: [], outlines: 0,
  coverage: 0, coverageHistory: [], state: null, bmodes: 0, mprs: [0, 0, 0], stats: null, reconnects: 0,
  recentImages: [],  // the last 64 images: {epoch, composite, preset, stride, frame, hash, at}
};

let ws = null;
let lastFrameShown = -1;
let viewSeq = 0;
const viewSent = new Map();  // view request seq -> time sent (ms)
let respondedSeq = 0;
let connectedAt = 0;  // frames that arrived before the page connected have no latency to show

function token() {
  const t = new URLSearchParams(location.search).get('token');
  return t ? '?token=' + encodeURIComponent(t) : '';
}

function connect() {
  ws = new WebSocket((location.protocol === 'https:' ? 'wss://' : 'ws://') + location.host + '/ws' + token());
  ws.binaryType = 'arraybuffer';
  ws.onopen = () => {
    pp5.connected = true;
    connectedAt = Date.now();
    $('connection').textContent = 'live';
    $('connection').className = 'good';
  };
  ws.onclose = () => {
    pp5.connected = false;
    $('connection').textContent = 'disconnected: retrying';
    $('connection').className = 'bad';
    pp5.reconnects++;
    setTimeout(connect, 1000);
  };
  ws.onmessage = (ev) => {
    if (typeof ev.data === 'string') return onText(ev.data);
    const dv = new DataView(ev.data);
    const n = dv.getUint32(0, true);
    const header = JSON.parse(new TextDecoder().decode(new Uint8Array(ev.data, 4, n)));
    const payload = new Uint8Array(ev.data, 4 + n);
    header.received_ms = Date.now();
    onMessage(header, payload);
  };
}

function send(msg) {
  if (ws && ws.readyState === WebSocket.OPEN) ws.send(JSON.stringify(msg));
}

function onText(text) {
  let m;
  try { m = JSON.parse(text); } catch (e) { return; }
  if (m.error) {
    pp5.errors.push(m.error);
    $('error').textContent = m.error;
    $('error').hidden = false;
    setTimeout(() => { $('error').hidden = true; }, 5000);
  }
}

function hash(bytes) {  // FNV-1a over a sample of the bytes: which images differ
  let h = 2166136261;
  const step = Math.max(1, Math.floor(bytes.length / 4096));
  for (let i = 0; i < bytes.length; i += step) h = Math.imul(h ^ bytes[i], 16777619);
  return (h >>> 0).toString(16) + ':' + bytes.length;
}

// A JPEG onto the canvas, at width x height (a coarse image of a drag is
// scaled up, smoothly) or at its own size.
async function drawJpeg(canvas, payload, width, height) {
  const bmp = await createImageBitmap(new Blob([payload], {type: 'image/jpeg'}));
  const w = width || bmp.width, h = height || bmp.height;
  if (canvas.width !== w || canvas.height !== h) {
    canvas.width = w;
    canvas.height = h;
  }
  const g = canvas.getContext('2d');
  g.imageSmoothingEnabled = true;
  g.drawImage(bmp, 0, 0, w, h);
  bmp.close();
}

async function onMessage(h, payload) {
  switch (h.type) {
    case 'image': return onImage(h, payload);
    case 'bmode':
      await drawJpeg($('bmode'), payload);
      pp5.bmodes++;
      $('bmode-caption').textContent =
          `B-mode frame ${h.index} · t = ${h.time_s.toFixed(3)} s · pose ${h.pose_ok ? 'OK' : 'INVALID'}`;
      return;
    case 'mpr':
      await drawJpeg($('mpr' + h.axis), payload);
      pp5.mprs[h.axis]++;
      return;
    case 'stats': return onStats(h);
    case 'state': return onState(h);
  }
}

async function onImage(h, payload) {
  const canvas = $('render');
  await drawJpeg(canvas, payload, h.width, h.height);
  const now = Date.now();
  pp5.images++;
  const hashed = hash(payload);
  pp5.distinct.add(hashed);
  if (pp5.distinct.size > 4096) pp5.distinct.delete(pp5.distinct.values().next().value);  // bounded: the oldest goes
  pp5.recentImages.push({epoch: h.epoch, composite: h.composite, preset: h.preset, stride: h.stride || 1,
                         frame: h.frame, hash: hashed, at: now});
  if (pp5.recentImages.length > 64) pp5.recentImages.shift();
  pp5.lastImage = h;
  pp5.epoch = h.epoch;
  pp5.shownTimes.push(now);
  while (pp5.shownTimes.length && now - pp5.shownTimes[0] > 1000) pp5.shownTimes.shift();
  if (h.frame >= 0 && h.arrivals) {
    for (const [f, t] of h.arrivals)
      if (f > lastFrameShown && t >= connectedAt) {
        pp5.latencies.push(now - t);
        // Where it went: the pipeline (arrival to the image on the host), the
        // host's encoder, the socket, and this page's decoding and drawing.
        if (h.assembled_ms && h.sent_ms)
          pp5.latencyParts.push({frame: f, at: now, total: now - t, pipeline: h.assembled_ms - t,
                                 encoder: h.sent_ms - h.assembled_ms, socket: h.received_ms - h.sent_ms,
                                 page: now - h.received_ms});
        if (pp5.latencies.length > 20000) {  // a long session: the latest only
          pp5.latencies.splice(0, 10000);
          pp5.latencyParts.splice(0, Math.max(0, pp5.latencyParts.length - 10000));
        }
      }
    lastFrameShown = Math.max(lastFrameShown, h.frame);
  }
  if (h.view_seq > respondedSeq && viewSent.has(h.view_seq)) {
    const sent = viewSent.get(h.view_seq);
    pp5.viewResponses.push({seq: h.view_seq, at: now, ms: now - sent, interactive: !!h.interactive,
                            pipeline: h.assembled_ms - sent, encoder: h.sent_ms - h.assembled_ms,
                            socket: h.received_ms - h.sent_ms, page: now - h.received_ms});
    respondedSeq = h.view_seq;
  }
  drawOutline(h);
  $('epoch').textContent = h.epoch + (h.interactive ? ' (fast)' : '');
  $('fps-out').textContent = pp5.shownTimes.length.toString();
}

function drawOutline(h) {
  const o = $('overlay');
  if (o.width !== h.width || o.height !== h.height) { o.width = h.width; o.height = h.height; }
  const g = o.getContext('2d');
  g.clearRect(0, 0, o.width, o.height);
  if (!h.outline || h.outline.length !== 4) return;
  g.strokeStyle = h.gap_warning ? '#ff5040' : '#40e0ff';
  g.lineWidth = Math.max(1, o.width / 256);
  g.beginPath();
  h.outline.forEach(([x, y], i) => (i ? g.lineTo(x, y) : g.moveTo(x, y)));
  g.closePath();
  g.stroke();
  pp5.outlines++;
}

function fmtMs(v) { return v === undefined || v === null ? '–' : v.toFixed(0) + ' ms'; }

function onStats(h) {
  pp5.stats = h;
  pp5.coverage = h.coverage;
  pp5.coverageHistory.push(h.coverage);
  $('fps-in').textContent = h.frames_per_s.toFixed(1);
  $('lat-med').textContent = fmtMs(h.latency_ms_median);
  $('lat-p95').textContent = fmtMs(h.latency_ms_p95);
  $('frames').textContent = h.frames;
  $('dropped').textContent = h.dropped;
  $('gp-load').textContent = (100 * h.gp_load).toFixed(0) + ' %';
  $('pp-load').textContent = (100 * h.pp_load).toFixed(0) + ' %';
  $('coverage').textContent = (100 * h.coverage).toFixed(1) + ' %';
  const w = $('warning');
  if (h.gap_warning) {
    w.textContent = `probe too fast: ${h.gap_mm.toFixed(1)} mm between frames (reconstruction fills ${h.gap_limit_mm.toFixed(1)} mm): holes`;
    w.hidden = false;
  } else {
    w.hidden = true;
  }
  const phase = h.paused ? 'paused'
      : h.serving ? 'input ended · steer the final volume'
      : h.ended ? 'input ended · making the final images' : 'acquiring';
  $('acq-state').textContent = phase +
      (h.recording ? ' · recording to ' + h.recording.split('/').pop() : '');
  $('acq-state').title = h.recording || '';
  $('pause').textContent = h.paused ? 'resume' : 'pause';
  $('record').textContent = h.recording ? 'stop recording' : 'start recording';
}

// ---- controls ----------------------------------------------------------------

let view = null;  // {azimuth, elevation, distance, pan: [x, y]}

// A choice the user just made keeps showing until the server's state agrees
// (or 2 s pass): a state sent before the server saw the change must not flip
// the control back.
const pending = {};
function userChose(key, value) { pending[key] = {value, until: performance.now() + 2000}; }
function shown(key, serverValue) {
  const p = pending[key];
  if (p && p.value !== serverValue && performance.now() < p.until) return p.value;
  delete pending[key];
  return serverValue;
}

function onState(h) {
  pp5.state = h;
  if (!view) view = {azimuth: h.azimuth, elevation: h.elevation, distance: h.distance, pan: h.pan};
  const sel = $('tf-preset');
  if (!sel.options.length) {
    for (const p of h.presets) sel.add(new Option(p, p));
    sel.add(new Option('custom', 'custom'));
  }
  sel.value = shown('preset', h.preset || 'custom');
  setSlider('tf-level', h.tf_level);
  setSlider('tf-window', h.tf_window);
  setSlider('tf-opacity', Math.round(100 * h.tf_opacity));
  setSlider('value-window', h.value_window);
  setSlider('value-level', h.value_level);
  setSlider('mpr-window', h.mpr_window);
  setSlider('mpr-level', h.mpr_level);
  const composite = shown('composite', h.composite);
  for (const r of document.querySelectorAll('input[name=composite]')) r.checked = r.value === composite;
  $('shade-mode').value = h.shading;
}

function setSlider(id, v) {
  const e = $(id);
  if (document.activeElement !== e) e.value = v;
  const out = $(id + '-v');
  if (out) out.textContent = e.value;
}

function sendView(interactive) {
  if (!view) return;
  viewSeq++;
  viewSent.set(viewSeq, Date.now());
  if (viewSent.size > 4096) viewSent.delete(viewSent.keys().next().value);  // the oldest
  send({type: 'view', seq: viewSeq, azimuth: view.azimuth, elevation: view.elevation, distance: view.distance,
        pan: view.pan, interactive});
}

let drag = null, pendingMove = false;
const render = $('render');
render.addEventListener('mousedown', (e) => {
  drag = {x: e.clientX, y: e.clientY, pan: e.shiftKey};
  render.style.cursor = 'grabbing';
  e.preventDefault();
});
window.addEventListener('mousemove', (e) => {
  if (!drag || !view) return;
  const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
  drag.x = e.clientX;
  drag.y = e.clientY;
  if (drag.pan) {
    const mmPerPx = 0.25 * view.distance;
    view.pan = [view.pan[0] - dx * mmPerPx, view.pan[1] + dy * mmPerPx];
  } else {
    view.azimuth = ((view.azimuth - dx * 0.5) % 360 + 540) % 360 - 180;
    view.elevation = Math.max(-89, Math.min(89, view.elevation + dy * 0.5));
  }
  // One view message per animation frame: a fast mouse does not flood the pipeline.
  if (!pendingMove) {
    pendingMove = true;
    requestAnimationFrame(() => { pendingMove = false; sendView(true); });
  }
});
window.addEventListener('mouseup', () => {
  if (!drag) return;
  drag = null;
  render.style.cursor = 'grab';
  sendView(false);  // refine to full resolution
});
render.addEventListener('wheel', (e) => {
  if (!view) return;
  e.preventDefault();
  view.distance = Math.max(0.5, Math.min(20, view.distance * Math.pow(1.1, Math.sign(e.deltaY))));
  sendView(false);
}, {passive: false});

function sendTf() {
  send({type: 'tf', level: +$('tf-level').value, window: +$('tf-window').value, opacity: $('tf-opacity').value / 100});
}
for (const id of ['tf-level', 'tf-window', 'tf-opacity']) $(id).addEventListener('change', sendTf);
$('tf-preset').addEventListener('change', (e) => {
  if (e.target.value === 'custom') return;
  userChose('preset', e.target.value);
  send({type: 'tf', preset: e.target.value});
});
for (const r of document.querySelectorAll('input[name=composite]'))
  r.addEventListener('change', () => {
    userChose('composite', r.value);
    send({type: 'composite', mode: r.value});
  });
const sendValueWindow = () => send({type: 'value_window', window: +$('value-window').value, level: +$('value-level').value});
$('value-window').addEventListener('change', sendValueWindow);
$('value-level').addEventListener('change', sendValueWindow);
const sendShading = () => send({type: 'shading', mode: $('shade-mode').value,
                                light: $('light-viewer').checked ? 'viewer' : 'direction',
                                light_azimuth: +$('light-az').value, light_elevation: +$('light-el').value});
for (const id of ['shade-mode', 'light-az', 'light-el', 'light-viewer']) $(id).addEventListener('change', sendShading);
for (let a = 0; a < 3; ++a)
  $('mpr-pos' + a).addEventListener('input', (e) => send({type: 'mpr', axis: a, position: e.target.value / 1000}));
const sendMprWindow = () => send({type: 'mpr_window', window: +$('mpr-window').value, level: +$('mpr-level').value});
$('mpr-window').addEventListener('change', sendMprWindow);
$('mpr-level').addEventListener('change', sendMprWindow);
$('mpr-tilt').addEventListener('input', (e) => send({type: 'mpr_tilt', degrees: +e.target.value}));
$('mpr-coverage').addEventListener('change', (e) => send({type: 'coverage_map', on: e.target.checked}));
$('pause').addEventListener('click', () => send({type: pp5.stats && pp5.stats.paused ? 'resume' : 'pause'}));
$('record').addEventListener('click', () => send({type: 'record', on: !(pp5.stats && pp5.stats.recording)}));

pp5.send = send;  // for the browser test's bad message
pp5.viewSent = () => viewSeq;  // view messages sent so far (the test's diagnostics)
pp5.viewSentAt = (seq) => viewSent.get(seq);  // when view message `seq` was sent (ms)
connect();
