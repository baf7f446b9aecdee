// armvision operator UI. Plain script, no build step, no external resources.
// The page is static: every element exists in index.html, and each state message only updates
// text, classes and attributes in place (rows of the tables are keyed by id / thread name).
'use strict';

// ---------------------------------------------------------------- token, URLs, HTTP

const TOKEN = new URLSearchParams(location.search).get('token');

/** Append the page's ?token=... (if any) to an API, WebSocket or stream path. */
function withToken(path) {
  if (!TOKEN) return path;
  return path + (path.includes('?') ? '&' : '?') + 'token=' + encodeURIComponent(TOKEN);
}

const $ = (id) => document.getElementById(id);

/** A server message fit for the banner: only the last line of anything that looks like a traceback. */
function readable(msg) {
  let text = String(msg == null ? '' : msg).trim();
  if (text.includes('Traceback (most recent call last)')) {
    const lines = text.split('\n').map((l) => l.trim()).filter(Boolean);
    text = lines[lines.length - 1] || 'server error';
  }
  return text;
}

/**
 * fetch() with the token (and a JSON body on a POST); resolves to the parsed JSON body, rejects with an Error whose message
 * is readable: the server's {"error": ...}, else "HTTP <status>: <body, 200 chars>".
 */
async function api(method, path, body) {
  const init = { method, headers: {} };
  if (method !== 'GET') {
    // The server takes a state-changing request only as JSON (an HTML form on another site
    // cannot send that), so every POST says so, with {} when it has no parameters.
    init.headers['Content-Type'] = 'application/json';
    init.body = JSON.stringify(body === undefined ? {} : body);
  }
  let resp;
  try {
    resp = await fetch(withToken(path), init);
  } catch (err) {
    throw Object.assign(new Error('Cannot reach the server (' + err.message + ')'), { status: 0 });
  }
  const text = await resp.text();
  let data = null;
  try { data = text ? JSON.parse(text) : null; } catch (_) { data = null; }
  if (!resp.ok) {
    let msg;
    if (data && typeof data.error === 'string') msg = readable(data.error);
    else if (data && data.detail !== undefined) {      // FastAPI's own errors (e.g. 422)
      const d = typeof data.detail === 'string' ? data.detail : JSON.stringify(data.detail);
      msg = `HTTP ${resp.status}: ${d.slice(0, 200)}`;
    } else msg = `HTTP ${resp.status}: ${text.trim().slice(0, 200)}`;
    throw Object.assign(new Error(msg), { status: resp.status });
  }
  return data;
}

// ---------------------------------------------------------------- small DOM helpers

/** Set text only when it changed (no needless layout work, no flicker). */
function setText(el, text) {
  const s = String(text);
  if (el.textContent !== s) el.textContent = s;
}

function setAttr(el, name, value) {
  if (value === null || value === undefined || value === false) {
    if (el.hasAttribute(name)) el.removeAttribute(name);
  } else if (el.getAttribute(name) !== String(value)) el.setAttribute(name, value);
}

/** Replace every class starting with `prefix` by prefix+value. */
function setPrefixedClass(el, prefix, value) {
  for (const c of [...el.classList]) if (c.startsWith(prefix) && c !== prefix + value) el.classList.remove(c);
  el.classList.add(prefix + value);
}

const isNum = (v) => typeof v === 'number' && Number.isFinite(v);
const fix = (v, d) => (isNum(v) ? v.toFixed(d) : '—');

/**
 * Bring `parent`'s children in line with `items`: one child per key (attribute `keyAttr`),
 * created once by make(), updated in place by update(el, item), removed when its key is gone.
 */
function syncKeyed(parent, items, keyAttr, keyOf, make, update) {
  const seen = new Set();
  let prev = null;
  for (const item of items) {
    const key = String(keyOf(item));
    seen.add(key);
    let el = parent.querySelector(`:scope > [${keyAttr}="${CSS.escape(key)}"]`);
    if (!el) {
      el = make();
      el.setAttribute(keyAttr, key);
    }
    // Keep the server's order without re-inserting children that are already in place.
    const want = prev ? prev.nextSibling : parent.firstChild;
    if (el !== want) parent.insertBefore(el, want);
    update(el, item);
    prev = el;
  }
  for (const el of [...parent.children]) if (!seen.has(el.getAttribute(keyAttr))) el.remove();
}

/** A <tr> with n empty cells, for syncKeyed. */
const makeRow = (n) => () => {
  const tr = document.createElement('tr');
  for (let i = 0; i < n; i++) tr.appendChild(document.createElement('td'));
  return tr;
};

// ---------------------------------------------------------------- error banner

function showError(msg) {
  setText($('error-text'), readable(msg));
  $('error').hidden = !msg;
}
function clearError() { showError(''); }

// ---------------------------------------------------------------- actions

const ACTIONS = ['home', 'sleep', 'gripper_open', 'gripper_close', 'calibrate',
  'follow_tag', 'follow_bottle', 'grab', 'analyze', 'place', 'sort'];
const buttonOf = (name) => $('btn-' + name.replace(/_/g, '-'));

let lastState = null;       // newest state JSON
let live = false;           // WebSocket open
const posting = new Set();  // actions whose POST is in flight (button held disabled)

function selectedTrackId() {
  const v = $('bottle-select').value;
  return v === '' ? null : Number(v);
}

function followDuration() {
  const v = parseFloat($('follow-duration').value);
  return Number.isFinite(v) && v > 0 ? v : null;
}

/** The JSON body each action takes (see the contract). */
function actionBody(name) {
  switch (name) {
    case 'grab':
    case 'analyze': return { track_id: selectedTrackId() };
    case 'follow_bottle': return { track_id: selectedTrackId(), duration_s: followDuration() };
    case 'follow_tag': return { tag_id: null, duration_s: followDuration() };
    case 'place': return { zone: $('zone-select').value || null };
    case 'sort': return { by: $('sort-by').value || null };
    default: return {};
  }
}

async function runAction(name) {
  posting.add(name);
  renderButtons();
  try {
    await api('POST', '/api/actions/' + name, actionBody(name));
    clearError();
  } catch (err) {
    showError(err.message);
  } finally {
    posting.delete(name);
    renderButtons();
  }
}

async function stopAll() {
  try {
    await api('POST', '/api/stop', {});
    clearError();
  } catch (err) {
    showError('Stop failed: ' + err.message);
  }
}

/** The zone list of the Place control, from the state's zones (kept when unchanged). */
function renderZones() {
  const zones = Object.keys((lastState && lastState.zones) || {});
  const select = $('zone-select');
  const shown = Array.from(select.options).map((o) => o.value);
  if (shown.join('\n') === zones.join('\n')) return;
  const keep = select.value;
  select.replaceChildren(...zones.map((z) => {
    const o = document.createElement('option');
    o.value = z; o.textContent = z;
    return o;
  }));
  if (zones.includes(keep)) select.value = keep;
}

/** Enable each action button as state.actions says (all off while disconnected). */
function renderButtons() {
  renderZones();
  const actions = (lastState && lastState.actions) || {};
  for (const name of ACTIONS) {
    const btn = buttonOf(name);
    const a = actions[name];
    if (a && a.label) setText(btn, a.label);
    let title = null;
    if (!live) title = 'Not connected to the server';
    else if (!a) title = 'Not offered by the server';
    else if (!a.enabled && a.reason) title = a.reason;
    btn.disabled = !live || !a || !a.enabled || posting.has(name);
    setAttr(btn, 'title', title);
  }
}

// ---------------------------------------------------------------- recording

let recordPosting = false;       // the Record / Stop recording POST is in flight
let recordShown = null;          // the state's recording, as last rendered
let recordErrorShown = null;     // a recording error already put in the banner

/** Record, or Stop recording: the server names the file (in record.dir). */
async function toggleRecording() {
  const active = !!(recordShown && recordShown.active);
  recordPosting = true;
  renderRecording(recordShown);
  try {
    const data = await api('POST', active ? '/api/recording/stop' : '/api/recording/start', {});
    if (data && data.recording) recordShown = data.recording;
  } catch (err) {
    showError(err.message);
  } finally {
    recordPosting = false;
    renderRecording(recordShown);
  }
}

function renderRecording(rec) {
  recordShown = rec || null;
  const active = !!(rec && rec.active);
  const btn = $('btn-record');
  setText(btn, active ? 'Stop recording' : 'Record');
  btn.classList.toggle('recording', active);
  btn.disabled = !live || recordPosting;
  let text = '';
  if (rec) {
    const mb = isNum(rec.bytes) ? ` ${(rec.bytes / 1e6).toFixed(1)} MB` : '';
    const dropped = isNum(rec.dropped) && rec.dropped > 0 ? `, ${rec.dropped} dropped` : '';
    if (rec.path) text = (active ? 'recording ' : 'recorded ') + String(rec.path) + mb + dropped;
    if (rec.live) text = (text ? text + '; ' : '') + 'live to Foxglove at ' + String(rec.live);
    if (rec.error && rec.error !== recordErrorShown) {
      recordErrorShown = rec.error;
      showError(rec.error);
    }
  }
  setText($('record-status'), text);
}

// ---------------------------------------------------------------- detectors

const DETECTORS = ['tags', 'objects', 'liquid'];
const detectorHold = {};  // name -> time until which state must not overwrite the checkbox

async function toggleDetector(name, box) {
  detectorHold[name] = Infinity;  // don't fight the user's click while the POST is in flight
  try {
    const data = await api('POST', '/api/detectors/' + name, { enabled: box.checked });
    if (data && data.detectors) applyDetectors(data.detectors, true);
  } catch (err) {
    box.checked = !box.checked;
    showError(err.message);
  } finally {
    // A state message sent just before the change may still arrive: ignore it briefly.
    detectorHold[name] = performance.now() + 500;
  }
}

function applyDetectors(dets, force) {
  for (const name of DETECTORS) {
    const box = $('det-' + name);
    if (!dets || typeof dets[name] !== 'boolean') continue;
    if (!force && (detectorHold[name] || 0) > performance.now()) continue;
    if (box.checked !== dets[name]) box.checked = dets[name];
  }
}

// ---------------------------------------------------------------- render: header, task, arm

const fmtAge = (s) => (isNum(s) ? (s < 10 ? s.toFixed(2) : s.toFixed(0)) + ' s' : '—');

function fmtValue(v) {
  if (isNum(v)) return Number.isInteger(v) ? String(v) : String(+v.toFixed(4));
  if (Array.isArray(v) && v.every(isNum)) return v.map(fmtValue).join(' ');
  if (v !== null && typeof v === 'object') {
    const s = JSON.stringify(v);
    return s.length > 120 ? s.slice(0, 117) + '…' : s;
  }
  return String(v);
}

function renderTask(task, now) {
  setText($('task-name'), task.name || '—');
  const phaseEl = $('task-phase');
  setText(phaseEl, task.phase);
  setPrefixedClass(phaseEl, 'phase-', task.phase);
  const active = task.phase === 'queued' || task.phase === 'running';
  // Running with no reported progress: indeterminate bar (no value attribute).
  setAttr($('task-progress'), 'value',
    isNum(task.progress) ? task.progress : (active ? null : 0));
  setText($('task-message'), task.message || '');
  setText($('task-error'), task.error ? readable(task.error) : '');
  let elapsed = '';
  if (isNum(task.started)) {
    const end = isNum(task.finished) ? task.finished : now;
    if (isNum(end)) elapsed = (end - task.started).toFixed(1) + ' s';
  }
  setText($('task-elapsed'), elapsed);
  const ended = ['succeeded', 'failed', 'stopped'].includes(task.phase);
  const result = ended && task.result ? Object.entries(task.result)
    .map(([k, v]) => k + ': ' + fmtValue(v)).join('\n') : '';
  setText($('task-result'), result);

  // The calibration panel mirrors a running calibration.
  const calibrating = task.name === 'calibrate' && active;
  $('cal-running').hidden = !calibrating;
  if (calibrating) {
    setAttr($('cal-progress'), 'value', isNum(task.progress) ? task.progress : null);
    setText($('cal-message'), task.message || task.phase);
  }
}

function renderArm(arm) {
  const names = arm.joint_names || [];
  const deg = arm.joints_deg;
  const lo = arm.lower_deg || [];
  const hi = arm.upper_deg || [];
  const joints = names.map((name, i) => ({ name, i }));
  syncKeyed($('joints').tBodies[0], joints, 'data-joint', (j) => j.name, makeRow(4), (row, { name, i }) => {
    const [nameCell, degCell, barCell, limCell] = row.cells;
    if (!degCell.id) {  // first time: build the static parts of the row
      degCell.id = 'joint-' + name;
      degCell.className = 'r num';
      limCell.className = 'r num muted';
      barCell.innerHTML = '<div class="range"><div class="range-mark"></div></div>';
    }
    setText(nameCell, name);
    const v = deg ? deg[i] : null;
    setText(degCell, fix(v, 1));
    setText(limCell, isNum(lo[i]) && isNum(hi[i]) ? `${lo[i].toFixed(0)} … ${hi[i].toFixed(0)}` : '');
    const mark = barCell.firstChild.firstChild;
    const span = hi[i] - lo[i];
    const ok = isNum(v) && isNum(span) && span > 0;
    const frac = ok ? Math.min(1, Math.max(0, (v - lo[i]) / span)) : 0;
    mark.hidden = !ok;
    mark.style.left = (frac * 100).toFixed(1) + '%';
    // Warn within 5 degrees of a limit.
    row.classList.toggle('near-limit', ok && (v - lo[i] < 5 || hi[i] - v < 5));
  });

  const ee = arm.ee;
  if (ee && ee.xyz_m && ee.rpy_deg) {
    const [x, y, z] = ee.xyz_m;
    const [r, p, yaw] = ee.rpy_deg;
    let s = `x ${fix(x, 3)} y ${fix(y, 3)} z ${fix(z, 3)} m · r ${fix(r, 1)} p ${fix(p, 1)} y ${fix(yaw, 1)} deg`;
    if (isNum(ee.sigma_mm)) s += `  ±${ee.sigma_mm.toFixed(1)} mm`;
    setText($('ee-pose'), s);
  } else setText($('ee-pose'), '—');
  setText($('finger'), isNum(arm.finger_m) ? (arm.finger_m * 1000).toFixed(1) + ' mm' : '—');
  $('arm-moving').hidden = !arm.moving;
}

function renderCalibration(cal) {
  setText($('cal-source'), cal.source || '—');
  setText($('cal-method'), cal.method || '—');
  setText($('cal-residual'), isNum(cal.residual_mm) ? cal.residual_mm.toFixed(2) + ' mm' : '—');
  const off = cal.joint_offsets_deg;
  setText($('cal-offsets'), Array.isArray(off) ? off.map((v) => fix(v, 2)).join('  ') + ' deg' : 'none');
  // The camera pose in use: the calibration as fusion refines it from the gripper tag.
  const cam = cal.camera || {};
  const T = cam.T_base_cam;
  setText(
    $('cal-camera'),
    Array.isArray(T)
      ? `x ${fix(T[0][3], 3)} y ${fix(T[1][3], 3)} z ${fix(T[2][3], 3)} m · ` +
          `${fix(cam.from_calibration_mm, 1)} mm, ${fix(cam.from_calibration_deg, 2)} deg from the calibration`
      : '—'
  );
  // Has the camera moved since calibration? The gripper tag as seen against the encoders.
  const d = cal.drift || {};
  setText(
    $('cal-drift'),
    isNum(d.translation_mm)
      ? `${fix(d.translation_mm, 1)} mm (limit ${fix(d.threshold_mm, 0)}), ` +
          (isNum(d.rotation_deg)
            ? `${fix(d.rotation_deg, 2)} deg (limit ${fix(d.threshold_deg, 1)})`
            : 'turn not checked (the tag is not face-on)')
      : 'not checked yet (show the gripper tag)'
  );
  const warn = $('cal-drifted');
  warn.hidden = !d.drifted;
  setText(warn, d.drifted ? `The camera has moved since calibration (${fix(d.translation_mm, 0)} mm, ${fix(d.rotation_deg, 1)} deg): recalibrate (Calibrate) or put it back.` : '');
}

// ---------------------------------------------------------------- render: threads, tracks, tags

/** ok / stale / error / off, from one thread's health. */
function healthStatus(h) {
  if (!h.enabled) return 'off';
  if (!h.alive) return 'error';
  if (h.stale) return 'stale';
  return h.ok && !h.last_error ? 'ok' : 'error';
}

function renderHealth(health) {
  const items = Object.entries(health || {}).map(([key, h]) => ({ key, ...h }));
  syncKeyed($('health').tBodies[0], items, 'data-thread', (h) => h.key, makeRow(7), (row, h) => {
    const c = row.cells;
    if (!c[6].firstChild) {
      c[2].className = c[3].className = c[4].className = 'r num';
      c[5].className = 'last-error';
      c[5].innerHTML = '<span></span>';
      c[6].innerHTML = '<span class="badge status"></span>';
    }
    setText(c[0], h.name || h.key);
    setText(c[1], h.enabled ? 'yes' : 'no');
    setText(c[2], fix(h.rate_hz, 1));
    setText(c[3], fmtAge(h.age_s));
    setText(c[4], isNum(h.errors) ? h.errors : '—');
    const err = h.last_error ? readable(h.last_error) : '';
    setText(c[5].firstChild, err);
    setAttr(c[5], 'title', err || null);
    const status = healthStatus(h);
    setText(c[6].firstChild, status);
    setPrefixedClass(c[6].firstChild, 'status-', status);
  });
}

const rgb = (c) => `rgb(${c.map((v) => Math.round(Number(v) || 0)).join(',')})`;

function fillText(liq) {
  if (liq && !isNum(liq.fill) && liq.unknown) return 'unknown';
  if (!liq || !isNum(liq.fill)) return '—';
  const std = isNum(liq.fill_std) ? ` ± ${(liq.fill_std * 100).toFixed(0)}` : '';
  return `${(liq.fill * 100).toFixed(0)}${std} %`;
}

function renderTracks(tracks) {
  syncKeyed($('tracks').tBodies[0], tracks, 'data-track-id', (t) => t.id, makeRow(7), (row, t) => {
    const c = row.cells;
    if (!c[6].firstChild) {
      c[0].className = c[2].className = c[3].className = c[4].className = c[5].className = 'r num';
      c[6].innerHTML = '<span class="swatch"></span>';
    }
    setText(c[0], t.id);
    setText(c[1], t.label);
    setText(c[2], Array.isArray(t.position_m) ? t.position_m.map((v) => fix(v, 3)).join(' ') : '—');
    setText(c[3], isNum(t.sigma_mm) ? `±${t.sigma_mm.toFixed(1)} mm` : '—');
    const mm = (v) => (isNum(v) ? (v * 1000).toFixed(0) : '—');
    setText(c[4], isNum(t.radius_m) || isNum(t.height_m) ? `${mm(t.radius_m)} / ${mm(t.height_m)}` : '—');
    setText(c[5], fillText(t.liquid));
    const sw = c[6].firstChild;
    const colour = t.liquid && Array.isArray(t.liquid.colour) ? rgb(t.liquid.colour) : '';
    if (sw.style.backgroundColor !== colour) sw.style.backgroundColor = colour;
    sw.hidden = !colour;
    setAttr(sw, 'title', colour || null);
  });
  $('tracks-empty').hidden = tracks.length > 0;
}

/** "nearest" plus one option per bottle; a selected bottle that vanished stays, marked lost. */
function renderBottleSelect(tracks) {
  const sel = $('bottle-select');
  const bottles = tracks.filter((t) => t.label === 'bottle');
  const wanted = new Map(bottles.map((t) => {
    const liq = t.liquid;
    const fill = liq && isNum(liq.fill) ? ` ${(liq.fill * 100).toFixed(0)}%` : liq && liq.unknown ? ' fill unknown' : '';
    return [String(t.id), `#${t.id} ${t.label}${fill}`];
  }));
  if (sel.value !== '' && !wanted.has(sel.value)) wanted.set(sel.value, `#${sel.value} (lost)`);
  for (const opt of [...sel.options]) {
    if (opt.value === '') continue;
    if (!wanted.has(opt.value)) opt.remove();
  }
  for (const [value, text] of wanted) {
    let opt = [...sel.options].find((o) => o.value === value);
    if (!opt) {
      opt = new Option(text, value);
      sel.add(opt);
    }
    setText(opt, text);
  }
}

function renderTags(tags) {
  const ul = $('tags');
  syncKeyed(ul, tags, 'data-tag-id', (t) => t.id, () => document.createElement('li'), (li, t) => {
    setText(li, `tag ${t.id}` + (isNum(t.distance_m) ? ` ${t.distance_m.toFixed(2)} m` : ''));
  });
  ul.classList.toggle('none', tags.length === 0);
}

// ---------------------------------------------------------------- render: everything

function render(state) {
  lastState = state;
  const mode = $('mode');
  setText(mode, state.mode ? String(state.mode).toUpperCase() : '—');
  setPrefixedClass(mode, 'mode-', state.mode || 'unknown');
  setText($('frame-index'), state.frame ? state.frame.index : '—');
  setText($('clock'), isNum(state.time) ? state.time.toFixed(1) + ' s' : '—');
  renderButtons();
  applyDetectors(state.detectors, false);
  if (state.task) renderTask(state.task, state.time);
  if (state.arm) renderArm(state.arm);
  if (state.calibration) renderCalibration(state.calibration);
  renderHealth(state.health);
  const tracks = state.tracks || [];
  renderTracks(tracks);
  renderBottleSelect(tracks);
  renderTags(state.tags || []);
  if (!recordPosting) renderRecording(state.recording);
}

// ---------------------------------------------------------------- WebSocket, with reconnect

const RECONNECT_MS = 1000;
let everLive = false;  // the socket has been open at least once

function setLive(on) {
  live = on;
  const conn = $('conn');
  setText(conn, on ? 'live' : 'disconnected');
  conn.classList.toggle('live', on);
  conn.classList.toggle('disconnected', !on);
  document.body.classList.toggle('offline', !on);
  for (const name of DETECTORS) $('det-' + name).disabled = !on;
  renderButtons();
  renderRecording(recordShown);
}

function connect() {
  const proto = location.protocol === 'https:' ? 'wss:' : 'ws:';
  const ws = new WebSocket(proto + '//' + location.host + withToken('/ws/state'));
  let gotMessage = false;
  ws.onopen = () => {
    // After a reconnect the MJPEG streams may have died with the old server: restart them.
    if (everLive) restartStreams();
    everLive = true;
    setLive(true);
  };
  ws.onmessage = (ev) => {
    let state;
    try { state = JSON.parse(ev.data); } catch (_) { return; }  // ignore a malformed message
    gotMessage = true;
    render(state);
  };
  ws.onclose = () => {
    setLive(false);
    // A socket refused before any message may be a token problem: ask over HTTP to say why.
    if (!gotMessage) probeState();
    setTimeout(connect, RECONNECT_MS);
  };
  // onerror is always followed by onclose, which does the work.
}

/** GET /api/state once: paints the page early and surfaces 401/403 in the banner. */
async function probeState() {
  try {
    render(await api('GET', '/api/state'));
  } catch (err) {
    if (err.status === 401 || err.status === 403) showError(err.message);
  }
}

// ---------------------------------------------------------------- video streams

const streamUrl = (view) => withToken('/stream.mjpg?view=' + view);

const STREAMS = { color: 'video', depth: 'depth' };  // view -> <img> id
const wantStream = (view) => view === 'color' || $('show-depth').checked;

/** (Re)start an <img> MJPEG stream: drop the src first so the browser opens a new request. */
function startStream(view) {
  const img = $(STREAMS[view]);
  img.removeAttribute('src');
  setTimeout(() => { if (wantStream(view)) img.src = streamUrl(view); }, 0);
}

function restartStreams() {
  for (const view of Object.keys(STREAMS)) if (wantStream(view)) startStream(view);
}

function setDepth(on) {
  $('depth').parentElement.hidden = !on;
  document.body.classList.toggle('with-depth', on);
  if (on) startStream('depth');
  else $('depth').removeAttribute('src');  // stops the stream
}

/** A stream that breaks (server restarting) retries after a second while the socket is live. */
function retryOnError(view) {
  const img = $(STREAMS[view]);
  img.addEventListener('error', () => {
    if (!img.getAttribute('src')) return;
    setTimeout(() => { if (live && wantStream(view)) startStream(view); }, RECONNECT_MS);
  });
}

// ---------------------------------------------------------------- wiring

function init() {
  for (const name of ACTIONS) buttonOf(name).addEventListener('click', () => runAction(name));
  $('btn-stop').addEventListener('click', stopAll);
  document.addEventListener('keydown', (ev) => {
    if (ev.key === 'Escape' && !ev.repeat) stopAll();
  });
  $('error-close').addEventListener('click', clearError);
  $('btn-record').addEventListener('click', toggleRecording);
  for (const name of DETECTORS) {
    const box = $('det-' + name);
    box.addEventListener('change', () => toggleDetector(name, box));
  }
  $('show-depth').checked = false;  // browsers may restore form state on reload
  $('show-depth').addEventListener('change', (ev) => setDepth(ev.target.checked));
  retryOnError('color');
  retryOnError('depth');

  setLive(false);
  $('video').src = streamUrl('color');
  probeState();
  connect();
}

init();
