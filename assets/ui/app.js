// vamos live view: plain JavaScript, no build step. Everything it shows comes from the
// token-checked API; the token lives in this tab's sessionStorage and travels only in the
// Authorization header (the live stream is read with fetch, as EventSource cannot send
// headers). Text from the server is only ever set as textContent.
//
// Robots are the rows: each robot's open sessions and its last ended ones (kept by the
// server with their whole timeline and alarms). A selected session's timeline has a time
// axis (seconds since its first frame); the recent alarms of every session, ended ones
// included, can be marked as false alarms by a robot or admin token.
'use strict';

const TOKEN_KEY = 'vamos-token';
const MAX_POINTS = 600;
const RECENT_ALARMS_SHOWN = 30;
const DETECTORS = [
  { key: 'score', label: 'fused score', thr: 'alarm', color: '#1d232a' },
  { key: 'e_c', label: 'e_c camera motion (px)', thr: 'e_c', color: '#1565c0' },
  { key: 'e_b', label: 'e_b body motion (px)', thr: 'e_b', color: '#6a1b9a' },
  { key: 'e_o', label: 'e_o flow prediction', thr: 'e_o', color: '#ef6c00' },
  { key: 'e_r', label: 'e_r scene residual', thr: 'e_r', color: '#00897b' },
  { key: 'e_k', label: 'e_k kinematic novelty', thr: 'e_k', color: '#827717' },
];

const state = {
  role: null,
  // The session shown: { id, ended } (ended: the ended session of that id, even while a
  // session of the same id is open).
  selected: null,
  summary: null,
  points: [],
  thresholds: {},
  abort: null,
  lastImages: 0,
  retry: null,
  robots: [],
  // Sessions the server keeps, by id (open or ended): what an alarm's link can select.
  known: new Map(),
};

const $ = (id) => document.getElementById(id);

function token() { return sessionStorage.getItem(TOKEN_KEY) || ''; }

function headers() {
  const t = token();
  return t ? { Authorization: 'Bearer ' + t } : {};
}

function say(text) { $('message').textContent = text || ''; }

function el(tag, text, cls) {
  const e = document.createElement(tag);
  if (text !== undefined && text !== null) e.textContent = String(text);
  if (cls) e.className = cls;
  return e;
}

async function api(path, opts = {}) {
  const r = await fetch(path, { ...opts, headers: { ...headers(), ...(opts.headers || {}) } });
  if (!r.ok) {
    let msg = r.status + ' ' + r.statusText;
    try { const j = await r.json(); if (j.error) msg = j.error; } catch (e) { /* not JSON */ }
    const err = new Error(msg);
    err.status = r.status;
    throw err;
  }
  return r;
}

const fmt = (v, d = 3) => (v === null || v === undefined ? '-' : Number(v).toPrecision(d));
const ms = (s) => (s === null || s === undefined ? '-' : (1000 * s).toFixed(0) + ' ms');

// Wall-clock time of a server time (seconds since the epoch), local, 24 h; a day other
// than today is named.
function clock(unixS, seconds = true) {
  if (unixS === null || unixS === undefined) return '-';
  const t = new Date(unixS * 1000);
  const two = (n) => String(n).padStart(2, '0');
  const hm = two(t.getHours()) + ':' + two(t.getMinutes()) + (seconds ? ':' + two(t.getSeconds()) : '');
  return t.toDateString() === new Date().toDateString() ? hm : t.toLocaleDateString() + ' ' + hm;
}

function duration(s) {
  if (s === null || s === undefined) return '-';
  if (s < 120) return s.toFixed(0) + ' s';
  if (s < 7200) return (s / 60).toFixed(0) + ' min';
  return (s / 3600).toFixed(1) + ' h';
}

// --- sign-in -------------------------------------------------------------------------

async function signIn() {
  try {
    const who = await (await api('/v1/whoami')).json();
    state.role = who.role;
    $('role').textContent = 'role: ' + who.role;
    $('role').className = 'pill ok';
    say('');
    connect();
    loadSide();
    loadAlarms();
  } catch (e) {
    state.role = null;
    $('role').textContent = 'not signed in';
    $('role').className = 'pill bad';
    say(e.status === 401 || e.status === 403
      ? 'This server needs a token: enter a viewer, robot or admin token (' + e.message + ').'
      : 'Cannot reach the server: ' + e.message);
    disconnect();
  }
}

$('login').addEventListener('submit', (ev) => {
  ev.preventDefault();
  const t = $('token').value.trim();
  if (t) sessionStorage.setItem(TOKEN_KEY, t); else sessionStorage.removeItem(TOKEN_KEY);
  $('token').value = '';
  signIn();
});

$('signout').addEventListener('click', () => {
  sessionStorage.removeItem(TOKEN_KEY);
  disconnect();
  state.role = null;
  $('role').textContent = 'not signed in';
  $('role').className = 'pill';
  $('robots').querySelector('tbody').replaceChildren();
  $('recent-alarms').replaceChildren();
  $('recent-alarms').dataset.key = '';
  $('alarms').dataset.key = '';
});

// --- the live stream (server-sent events over fetch) -----------------------------------

function disconnect() {
  if (state.abort) state.abort.abort();
  state.abort = null;
  clearTimeout(state.retry);
  $('conn').textContent = 'offline';
  $('conn').className = 'pill';
}

function connect() {
  disconnect();
  const ctrl = new AbortController();
  state.abort = ctrl;
  let q = '';
  if (state.selected) {
    q = '?session=' + encodeURIComponent(state.selected.id) + (state.selected.ended ? '&ended=true' : '');
  }
  readStream('/v1/live' + q, ctrl).catch((e) => {
    if (ctrl.signal.aborted) return;
    $('conn').textContent = 'reconnecting';
    $('conn').className = 'pill bad';
    if (e.status === 401 || e.status === 403) { signIn(); return; }
    say('Live stream lost (' + e.message + '); reconnecting.');
    state.retry = setTimeout(connect, 1500);
  });
}

async function readStream(path, ctrl) {
  const r = await api(path, { signal: ctrl.signal, headers: { Accept: 'text/event-stream' } });
  $('conn').textContent = 'live';
  $('conn').className = 'pill ok';
  const reader = r.body.getReader();
  const dec = new TextDecoder();
  let buf = '';
  for (;;) {
    const { value, done } = await reader.read();
    if (done) throw new Error('the server ended the stream');
    buf += dec.decode(value, { stream: true });
    let i;
    while ((i = buf.indexOf('\n\n')) >= 0) {
      const block = buf.slice(0, i);
      buf = buf.slice(i + 2);
      let name = 'message';
      const data = [];
      for (const line of block.split('\n')) {
        if (line.startsWith('event:')) name = line.slice(6).trim();
        else if (line.startsWith('data:')) data.push(line.slice(5).replace(/^ /, ''));
      }
      if (data.length) onEvent(name, JSON.parse(data.join('\n')));
    }
  }
}

function onEvent(name, data) {
  // `sessions` (the open sessions alone) is what `robots` also carries.
  if (name === 'robots') renderRobots(data.robots);
  else if (name === 'timeline') onTimeline(data);
  else if (name === 'alarms') renderAlarms($('alarms'), data.alarms, false);
  else if (name === 'gone') {
    say(data.error);
    $('detail').hidden = true;
    $('selected-title').textContent = 'Session ' + data.session + ' is no longer kept';
    state.selected = null;
    connect();
  }
}

// --- robots --------------------------------------------------------------------------

// A session's state as shown: live / detached / episode, ALARM, degraded, ended.
function statePills(s) {
  const pills = [];
  if (s.state === 'ended') pills.push(['ended', 'ended']);
  else if (s.state === 'streaming') pills.push(['live', 'live']);
  else pills.push([s.state, 'live']);
  if (s.alarm_on) pills.push(['ALARM', 'alarm']);
  if (s.degraded) pills.push(['degraded', 'degraded']);
  const box = el('span');
  for (const [text, cls] of pills) {
    const p = el('span', text, 'state ' + cls);
    if (cls === 'degraded') {
      p.title = s.frames_lost + ' image(s) lost before scored frames (dropped by a full queue or refused)' +
        (s.state === 'ended' ? '' : ', some among the last 100 frames');
    }
    box.appendChild(p);
    box.appendChild(document.createTextNode(' '));
  }
  return box;
}

function isSelected(s, ended) {
  return state.selected && state.selected.id === s.id && state.selected.ended === ended;
}

function sessionChip(s, ended) {
  const b = el('button', null, 'session ' + (ended ? 'ended' : 'live'));
  b.type = 'button';
  b.dataset.id = s.id;
  b.dataset.state = ended ? 'ended' : 'live';
  if (s.degraded) b.classList.add('degraded');
  if (s.anomalies > 0 || s.alarm_on) b.classList.add('alarmed');
  if (isSelected(s, ended)) b.classList.add('selected');
  b.textContent = s.id + (ended ? ' \u00b7 ended ' + clock(s.ended_unix_s, false) : ' \u00b7 live');
  b.title = s.id + ': ' + s.frames_scored + ' frames, ' + s.dropped + ' dropped, ' + s.frames_lost + ' lost, ' +
    (ended ? 'ran ' + duration(s.age_s) + (s.end_reason ? ' (' + s.end_reason + ')' : '') : 'open ' + duration(s.age_s));
  b.addEventListener('click', (ev) => { ev.stopPropagation(); select(s.id, ended); });
  return b;
}

function renderRobots(robots) {
  state.robots = robots;
  state.known = new Map();
  const body = $('robots').querySelector('tbody');
  const rows = robots.map((r) => {
    const open = r.sessions.map((x) => x.summary);
    for (const s of r.ended) state.known.set(s.id, true);
    for (const s of open) state.known.set(s.id, false);
    const current = open.length ? open[0] : null;
    const shown = current || r.ended[0];
    const ended = !current;
    const tr = el('tr');
    tr.dataset.robot = r.robot_id;
    tr.dataset.state = ended ? 'ended' : (shown.degraded ? 'degraded' : 'live');
    if (shown.alarm_on) tr.classList.add('alarm');
    if (state.selected && [...open, ...r.ended].some((s) => s.id === state.selected.id)) tr.classList.add('selected');
    const a = r.last_alarm;
    const cells = [
      el('td', r.robot_id || '(no robot id)'),
      el('td', null, 'state-cell'),
      el('td', shown.id),
      el('td', shown.profile + ' / ' + shown.model),
      el('td', shown.frame_rate_hz ? shown.frame_rate_hz.toFixed(1) : '-'),
      el('td', ms(shown.latency_s)),
      el('td', shown.dropped + ' / ' + shown.frames_lost, 'drops'),
      el('td', shown.frames_scored),
      el('td', a ? a.detector + ' at ' + clock(a.started_unix_s) + (a.false_alarm ? ' (false)' : '') : '-'),
      el('td', null, 'recent'),
    ];
    cells[1].appendChild(statePills(shown));
    cells[2].title = shown.id;
    cells[3].title = cells[3].textContent;
    cells[6].title = shown.dropped + ' image(s) dropped, ' + shown.frames_lost + ' lost before scored frames';
    for (const s of open) cells[9].appendChild(sessionChip(s, false));
    for (const s of r.ended) cells[9].appendChild(sessionChip(s, true));
    for (const c of cells) tr.appendChild(c);
    tr.addEventListener('click', () => select(shown.id, ended));
    return tr;
  });
  body.replaceChildren(...rows);
  $('no-robots').hidden = robots.length > 0;
}

function select(id, ended) {
  state.selected = { id, ended: !!ended };
  state.points = [];
  state.summary = null;
  state.lastImages = 0;
  $('detail').hidden = false;
  $('selected-title').textContent = 'Session ' + id;
  $('timeline').dataset.points = '0';
  $('overlay').dataset.frame = '0';
  $('overlay').dataset.map = '0';
  $('alarms').dataset.key = '';
  $('alarms').replaceChildren();
  say('');
  renderRobots(state.robots);
  connect();
}

// --- timeline ------------------------------------------------------------------------

function onTimeline(data) {
  state.thresholds = data.thresholds || {};
  const s = data.session;
  const wasEnded = state.summary && state.summary.state === 'ended';
  state.summary = s;
  if (data.replace) state.points = data.points.slice();
  else for (const p of data.points) state.points.push(p);
  if (s.state !== 'ended' && state.points.length > MAX_POINTS) state.points.splice(0, state.points.length - MAX_POINTS);
  const ended = s.state === 'ended';
  $('selected-title').textContent = 'Session ' + s.id + ' of ' + (s.robot_id || '(no robot id)') +
    (ended ? ' \u2014 ended ' + clock(s.ended_unix_s) : ' \u2014 ' + s.state);
  $('session-facts').textContent = s.profile + ' / ' + s.model + (s.task ? ', task ' + s.task : '') + ', opened ' + clock(s.opened_unix_s) +
    ', ' + (ended ? 'ran ' : 'open ') + duration(s.age_s) + ', ' + s.frames_scored + ' frames scored, ' + s.dropped + ' dropped, ' +
    s.frames_lost + ' lost, latency ' + ms(s.latency_s) + (s.end_reason ? ' \u2014 ended: ' + s.end_reason : '');
  const banner = $('degraded');
  banner.hidden = !s.degraded;
  banner.textContent = s.degraded
    ? 'Degraded: ' + s.frames_lost + ' image(s) lost before scored frames (a full queue or refused images)' +
      (ended ? ' during the session' : ', some among its last 100 frames') +
      '; the frame after each gap has no motion score and cannot alarm (amber ticks on the timeline).'
    : '';
  // What the profile asks for and cannot do (a threshold's fallback, a detector that
  // cannot run): said, never silent.
  const notes = $('profile-notes');
  notes.replaceChildren(...(s.notes || []).map(n => el('li', n)));
  notes.hidden = !(s.notes || []).length;
  // An ended session's frames are not kept (each alarm keeps the frame at its start): its
  // timeline takes the room of the latest frame.
  $('frame-box').hidden = ended;
  drawTimeline();
  if (ended) {
    if (!wasEnded) {
      const c = $('overlay');
      c.getContext('2d').clearRect(0, 0, c.width, c.height);
    }
    return;
  }
  const now = Date.now();
  if (data.points.length && now - state.lastImages > 700) {
    state.lastImages = now;
    drawImages(state.selected.id);
  }
}

// Tick spacing near `raw`: 1, 2 or 5 times a power of ten.
function niceStep(raw) {
  const p = 10 ** Math.floor(Math.log10(raw));
  for (const m of [1, 2, 5, 10]) if (m * p >= raw) return m * p;
  return 10 * p;
}

function drawTimeline() {
  const c = $('timeline');
  const g = c.getContext('2d');
  const pts = state.points;
  g.clearRect(0, 0, c.width, c.height);
  const rows = DETECTORS.filter((d) => d.key === 'score' || pts.some((p) => p[d.key] !== null && p[d.key] !== undefined));
  const axisH = 34;
  const h = (c.height - axisH) / rows.length;
  const x0 = 8;
  const w = c.width - 16;
  // Time: seconds since the session's first frame (image stamps).
  const origin = state.summary && state.summary.first_stamp_ns !== null && state.summary.first_stamp_ns !== undefined
    ? state.summary.first_stamp_ns : (pts.length ? pts[0].stamp_ns : 0);
  const tOf = (p) => (p.stamp_ns - origin) / 1e9;
  const t0 = pts.length ? tOf(pts[0]) : 0;
  let t1 = pts.length ? tOf(pts[pts.length - 1]) : 1;
  if (!(t1 > t0)) t1 = t0 + 1;
  const xOfT = (t) => x0 + (w * (t - t0)) / (t1 - t0);
  const xOf = (i) => xOfT(tOf(pts[i]));
  const band = (i) => Math.max(1, (i + 1 < pts.length ? xOf(i + 1) : x0 + w) - xOf(i));
  // The axis: ticks every 1, 2 or 5 x 10^k seconds, grid lines through every row.
  const step = niceStep((t1 - t0) / 6);
  const decimals = Math.max(0, -Math.floor(Math.log10(step)));
  const ticks = [];
  for (let t = Math.ceil(t0 / step - 1e-9) * step; t <= t1 + 1e-9; t += step) ticks.push(t);
  const plotBottom = c.height - axisH;
  g.strokeStyle = '#eceff2';
  g.lineWidth = 1;
  for (const t of ticks) { g.beginPath(); g.moveTo(xOfT(t), 4); g.lineTo(xOfT(t), plotBottom); g.stroke(); }
  g.strokeStyle = '#8a949e';
  g.beginPath(); g.moveTo(x0, plotBottom + 2); g.lineTo(x0 + w, plotBottom + 2); g.stroke();
  g.fillStyle = '#56606b';
  g.font = '11px system-ui';
  const labels = [];
  for (const t of ticks) {
    const x = xOfT(t);
    g.beginPath(); g.moveTo(x, plotBottom + 2); g.lineTo(x, plotBottom + 6); g.stroke();
    const label = t.toFixed(decimals) + ' s';
    labels.push(label);
    const tw = g.measureText(label).width;
    g.fillText(label, Math.min(Math.max(x - tw / 2, x0), x0 + w - tw), plotBottom + 17);
  }
  const title = 'time since the session\u2019s first frame (s)' + (state.summary && state.summary.state === 'ended' ? ', whole session' : '');
  g.fillText(title, x0 + w - g.measureText(title).width, plotBottom + 31);
  c.dataset.ticks = labels.join(',');
  c.dataset.axis = 'seconds';
  rows.forEach((d, r) => {
    const top = r * h + 16;
    const ph = h - 24;
    const thr = d.thr ? state.thresholds[d.thr] : null;
    const vals = pts.map((p) => p[d.key]).filter((v) => v !== null && v !== undefined);
    let max = Math.max(1e-9, ...vals, thr !== null && thr !== undefined ? thr * 1.5 : 0);
    // Trigger-band scores (1e6 and above) would flatten the plot: cap the axis.
    if (d.key === 'score' && thr && max > thr * 4) max = thr * 4;
    const yOf = (v) => top + ph - ph * Math.min(v / max, 1);
    // Warm-up greyed, alarms shaded, images lost before a frame ticked in amber.
    pts.forEach((p, i) => {
      if (p.warming_up) { g.fillStyle = 'rgba(0,0,0,0.07)'; g.fillRect(xOf(i), top, band(i), ph); }
      if (p.alarm) { g.fillStyle = 'rgba(198,40,40,0.12)'; g.fillRect(xOf(i), top, band(i), ph); }
      if (p.frames_lost > 0) { g.fillStyle = '#ef6c00'; g.fillRect(xOf(i) - 1, top, 2, 6); }
    });
    g.fillStyle = '#56606b';
    g.font = '11px system-ui';
    const last = vals.length ? vals[vals.length - 1] : null;
    g.fillText(d.label + '  ' + fmt(last) + (thr ? '  (threshold ' + fmt(thr) + ')' : ''), x0, top - 4);
    if (thr !== null && thr !== undefined) {
      g.strokeStyle = '#c62828';
      g.setLineDash([5, 4]);
      g.beginPath(); g.moveTo(x0, yOf(thr)); g.lineTo(x0 + w, yOf(thr)); g.stroke();
      g.setLineDash([]);
    }
    g.strokeStyle = d.color;
    g.lineWidth = 1.5;
    g.beginPath();
    let pen = false;
    pts.forEach((p, i) => {
      const v = p[d.key];
      if (v === null || v === undefined) { pen = false; return; }
      if (pen) g.lineTo(xOf(i), yOf(v)); else g.moveTo(xOf(i), yOf(v));
      pen = true;
    });
    g.stroke();
    g.lineWidth = 1;
  });
  c.dataset.points = String(pts.length);
}

// --- latest frame with the anomaly map -------------------------------------------------

async function bitmap(path) {
  const r = await api(path);
  return createImageBitmap(await r.blob());
}

function stillShown(id) {
  return state.selected && state.selected.id === id && !state.selected.ended &&
    !(state.summary && state.summary.state === 'ended');
}

async function drawImages(id) {
  const c = $('overlay');
  const g = c.getContext('2d');
  try {
    const frame = await bitmap('/v1/sessions/' + encodeURIComponent(id) + '/frame');
    if (!stillShown(id)) return;
    c.width = frame.width;
    c.height = frame.height;
    g.drawImage(frame, 0, 0);
    c.dataset.frame = String(Number(c.dataset.frame) + 1);
  } catch (e) { return; }
  let map;
  try { map = await bitmap('/v1/sessions/' + encodeURIComponent(id) + '/map'); } catch (e) { return; }
  if (!stillShown(id)) return;
  // Gray map -> red with alpha = value, scaled over the frame.
  const m = document.createElement('canvas');
  m.width = map.width;
  m.height = map.height;
  const mg = m.getContext('2d');
  mg.drawImage(map, 0, 0);
  const img = mg.getImageData(0, 0, m.width, m.height);
  for (let i = 0; i < img.data.length; i += 4) {
    const v = img.data[i];
    img.data[i] = 255; img.data[i + 1] = 0; img.data[i + 2] = 0; img.data[i + 3] = Math.round(v * 0.7);
  }
  mg.putImageData(img, 0, 0);
  g.imageSmoothingEnabled = true;
  g.drawImage(m, 0, 0, c.width, c.height);
  c.dataset.map = String(Number(c.dataset.map) + 1);
}

// --- alarms --------------------------------------------------------------------------

const thumbs = new Map();

async function thumb(img, id) {
  if (thumbs.has(id)) { img.src = thumbs.get(id); return; }
  try {
    const url = URL.createObjectURL(await (await api('/v1/alarms/' + encodeURIComponent(id) + '/thumbnail')).blob());
    thumbs.set(id, url);
    img.src = url;
  } catch (e) { img.alt = 'no thumbnail'; }
}

// The alarms in `ul` (the selected session's, or with `recent` every session's), each
// with its thumbnail, its values against the thresholds, and the button that marks it as
// a false alarm (disabled for a viewer and once marked).
function renderAlarms(ul, alarms, recent) {
  const key = JSON.stringify([state.role, alarms.map((a) => [a.id, a.end_frame, !!a.false_alarm, a.frames_flagged])]);
  if (key === ul.dataset.key) return;
  ul.dataset.key = key;
  const items = alarms.map((a) => {
    const li = el('li');
    li.dataset.id = a.id;
    li.dataset.session = a.session_id;
    if (a.false_alarm) li.classList.add('marked');
    const img = el('img');
    img.alt = 'frame at the alarm start';
    thumb(img, a.id);
    li.appendChild(img);
    const facts = el('div', null, 'facts');
    const head = el('strong', a.detector + (a.detectors.length > 1 ? ' (+' + a.detectors.slice(1).join(', ') + ')' : ''));
    facts.appendChild(head);
    if (recent) {
      facts.appendChild(document.createTextNode(' '));
      const where = el('a', (a.robot_id || '(no robot id)') + ' / ' + a.session_id, 'session-link');
      where.href = '#';
      where.title = 'show this session';
      where.addEventListener('click', (ev) => {
        ev.preventDefault();
        if (state.known.has(a.session_id)) select(a.session_id, state.known.get(a.session_id));
        else say('Session ' + a.session_id + ' is no longer kept; its alarm is.');
      });
      facts.appendChild(where);
    }
    facts.appendChild(el('div', 'started ' + clock(a.started_unix_s) + ', frames ' + a.start_frame + ' - ' + (a.end_frame ?? 'on') +
      ', ' + a.frames_flagged + ' flagged'));
    const t = a.thresholds;
    if (!recent) {
      facts.appendChild(el('div', 'at start: score ' + fmt(a.start.score) + ' (threshold ' + fmt(t.alarm) + '), e_c ' + fmt(a.start.e_c) +
        ' (' + fmt(t.e_c) + '), e_b ' + fmt(a.start.e_b) + ' (' + fmt(t.e_b) + '), e_o ' + fmt(a.start.e_o) + ' (' + fmt(t.e_o) + '), e_r ' +
        fmt(a.start.e_r) + ' (' + fmt(t.e_r) + '), e_k ' + fmt(a.start.e_k) + ' (' + fmt(t.e_k) + ')'));
    } else {
      facts.appendChild(el('div', 'peak score ' + fmt(a.peak.score) + ' (threshold ' + fmt(t.alarm) + ')'));
    }
    facts.appendChild(el('div', a.false_alarm ? 'marked as a false alarm (' + a.false_alarm.by_role + ')' : a.id, 'muted'));
    li.appendChild(facts);
    const b = el('button', a.false_alarm ? 'False alarm' : 'Mark false alarm', 'mark');
    b.disabled = !!a.false_alarm || state.role === 'viewer';
    if (state.role === 'viewer') b.title = 'a viewer token cannot mark alarms';
    b.addEventListener('click', () => mark(a.id, b));
    li.appendChild(b);
    return li;
  });
  ul.replaceChildren(...items);
}

// The recent alarms of every session (ended ones included), newest first.
async function loadAlarms() {
  if (!state.role) return;
  try {
    const alarms = (await (await api('/v1/alarms')).json()).alarms || [];
    renderAlarms($('recent-alarms'), alarms.slice(0, RECENT_ALARMS_SHOWN), true);
    $('no-alarms').hidden = alarms.length > 0;
  } catch (e) { $('no-alarms').hidden = false; $('no-alarms').textContent = e.message; }
}

async function mark(id, button) {
  button.disabled = true;
  try {
    await api('/v1/alarms/' + encodeURIComponent(id) + '/false-alarm', {
      method: 'POST', headers: { 'Content-Type': 'application/json' }, body: JSON.stringify({ note: 'marked on the live view' }),
    });
    say('Alarm ' + id + ' marked as a false alarm.');
    $('alarms').dataset.key = '';
    $('recent-alarms').dataset.key = '';
    loadAlarms();
    loadSide();
  } catch (e) {
    say('Not marked: ' + e.message);
    button.disabled = false;
  }
}

// --- jobs, profiles, marked alarms ------------------------------------------------------

async function loadSide() {
  try {
    const jobs = (await (await api('/v1/jobs')).json()).jobs || [];
    const ul = el('ul');
    for (const j of jobs.slice(-10).reverse()) {
      const thr = j.calibration ? calibrationSummary(j.calibration) : '';
      const kind = j.proposal ? ' recalibration' : '';
      const li = el('li', '#' + j.id + ' ' + j.profile + kind + ': ' + j.state + (j.proposal ? '' : thr) + (j.error ? ' (' + j.error + ')' : ''));
      if (j.proposal && j.state === 'succeeded') li.appendChild(proposal(j));
      for (const n of j.notes || []) li.appendChild(el('div', n, 'muted note'));
      ul.appendChild(li);
    }
    $('jobs').replaceChildren(jobs.length ? ul : el('span', 'No calibration job.'));
  } catch (e) { $('jobs').textContent = e.status === 403 ? 'Calibration jobs need an admin token.' : e.message; }
  try {
    const profiles = (await (await api('/v1/profiles')).json()).profiles || [];
    const ul = el('ul');
    // Each profile's nominal set: the recorded sessions of its false alarms.
    const nominal = await Promise.all(profiles.map((p) => (p.name
      ? api('/v1/profiles/' + encodeURIComponent(p.name) + '/nominal').then((r) => r.json()).then((b) => b.episodes, () => null)
      : null)));
    profiles.forEach((p, i) => {
      const count = nominal[i] === null ? '' : ', ' + nominal[i].length + ' nominal episode(s) from false alarms';
      const li = el('li', (p.name || p) + (p.alarm_threshold !== undefined ? ': alarm threshold ' + fmt(p.alarm_threshold) : '') + count);
      if (nominal[i] && nominal[i].length) li.appendChild(nominalList(nominal[i]));
      if (state.role === 'admin' && p.name && nominal[i] && nominal[i].length) li.appendChild(recalibrateButton(p.name));
      ul.appendChild(li);
    });
    $('profiles').replaceChildren(profiles.length ? ul : el('span', 'No profile.'));
  } catch (e) { $('profiles').textContent = e.status === 403 ? 'Profiles need a robot or admin token.' : e.message; }
  try {
    const marked = (await (await api('/v1/alarms?marked=true')).json()).alarms || [];
    const ul = el('ul');
    for (const a of marked.slice(-10).reverse()) ul.appendChild(el('li', a.id + ' ' + a.profile + ' ' + a.detector + ' (' + a.false_alarm.by_role + ')'));
    $('marked').replaceChildren(marked.length ? ul : el('span', 'None yet.'));
  } catch (e) { $('marked').textContent = e.message; }
}

// A calibration's result in one line: the detector thresholds, the training maximum and
// the conformal threshold with what it rests on.
function calibrationSummary(c) {
  const t = c.thresholds || {};
  const parts = ['e_c ' + fmt(t.e_c), 'e_b ' + fmt(t.e_b), 'max ' + fmt(c.score_max)];
  if (c.conformal) {
    parts.push('conformal ' + fmt(c.conformal.threshold) + ' (' + c.conformal.n + ' held out, alpha ' + c.conformal.alpha + ')');
  }
  return ' \u2014 ' + (c.training_frames || 0) + ' training frames: ' + parts.join(', ');
}

// A recalibration's proposal: each threshold now and proposed, the episodes' largest
// scores before and after, and (admin, not applied yet) the button that applies it.
function proposal(j) {
  const p = j.proposal;
  const box = el('div', null, 'proposal');
  const rows = ['alarm', 'e_c', 'e_b', 'e_o', 'e_r', 'e_k']
    .filter((k) => p.current[k] != null || p.proposed[k] != null)
    .map((k) => k + ' ' + fmt(p.current[k]) + ' \u2192 ' + fmt(p.proposed[k]));
  box.appendChild(el('div', 'thresholds: ' + rows.join(', ')));
  box.appendChild(el('div', p.episodes.length + ' nominal episode(s), largest score ' +
    p.episodes.map((e) => fmt(e.max_score_before) + ' \u2192 ' + fmt(e.max_score_after)).join(', '), 'muted'));
  box.appendChild(proposalPlot(p));
  if (p.applied_unix_s) {
    box.appendChild(el('div', 'applied', 'muted'));
  } else if (state.role === 'admin') {
    const b = el('button', 'Apply', 'apply');
    b.addEventListener('click', async () => {
      b.disabled = true;
      try {
        await api('/v1/jobs/' + j.id + '/apply', { method: 'POST' });
        say('Job ' + j.id + "'s thresholds applied to " + j.profile + '.');
        loadSide();
      } catch (e) { say('Not applied: ' + e.message); b.disabled = false; }
    });
    box.appendChild(b);
  }
  return box;
}

// Each nominal episode's largest fused score before (grey) and after (blue) the proposal,
// on a log axis, against the alarm threshold now (red, dashed) and proposed (green).
function proposalPlot(p) {
  const rowH = 16;
  const c = el('canvas', null, 'proposal-plot');
  c.width = 420;
  c.height = 24 + rowH * 2 * p.episodes.length;
  const g = c.getContext('2d');
  const values = p.episodes.flatMap((e) => [e.max_score_before, e.max_score_after])
    .concat([p.current.alarm, p.proposed.alarm]).filter((v) => v !== null && v > 0);
  const lo = Math.log10(Math.min(...values, 1e-3)) - 0.2;
  const hi = Math.log10(Math.max(...values, 1)) + 0.2;
  const x0 = 110;
  const w = c.width - x0 - 10;
  const xOf = (v) => x0 + (w * (Math.log10(Math.max(v, 10 ** lo)) - lo)) / (hi - lo);
  g.font = '11px system-ui';
  p.episodes.forEach((e, i) => {
    const y = 8 + i * 2 * rowH;
    g.fillStyle = '#56606b';
    g.fillText(e.name.slice(0, 16), 2, y + rowH);
    g.fillStyle = '#9e9e9e';
    g.fillRect(x0, y, xOf(e.max_score_before) - x0, rowH - 3);
    g.fillStyle = '#1565c0';
    g.fillRect(x0, y + rowH, xOf(e.max_score_after) - x0, rowH - 3);
  });
  const line = (v, color, dash) => {
    if (v === null || !(v > 0)) return;
    g.strokeStyle = color;
    g.setLineDash(dash);
    g.beginPath();
    g.moveTo(xOf(v), 2);
    g.lineTo(xOf(v), c.height - 14);
    g.stroke();
  };
  line(p.current.alarm, '#c62828', [4, 3]);
  line(p.proposed.alarm, '#2e7d32', []);
  g.setLineDash([]);
  g.fillStyle = '#56606b';
  g.fillText('largest score, log axis; red: alarm now, green: proposed', x0, c.height - 2);
  return c;
}

// A profile's nominal set, one line per recorded session.
function nominalList(episodes) {
  const ul = el('ul', null, 'nominal');
  for (const e of episodes) {
    ul.appendChild(el('li', e.session_id + ' (' + (e.finished ? Math.round((e.bytes || 0) / 1024) + ' KiB' : 'recording') +
      ', ' + e.alarms.length + ' false alarm(s))', 'muted'));
  }
  return ul;
}

// Starts a recalibration of a profile from its nominal set (its false alarms' sessions).
function recalibrateButton(name) {
  const b = el('button', 'Recalibrate from false alarms', 'recalibrate');
  b.addEventListener('click', async () => {
    b.disabled = true;
    try {
      const r = await (await api('/v1/profiles/' + encodeURIComponent(name) + '/recalibrate', { method: 'POST' })).json();
      say('Recalibration job ' + r.job + ' started for ' + name + ': its proposal shows under Calibration jobs.');
      loadSide();
    } catch (e) { say('Not started: ' + e.message); }
    b.disabled = false;
  });
  return b;
}

signIn();
// Jobs, profiles and marked alarms change rarely: refreshed every 10 s while signed in.
setInterval(() => { if (state.role) loadSide(); }, 10000);
// The recent alarms change with every session: refreshed every 2 s while signed in.
setInterval(loadAlarms, 2000);
