// ima console: live state over server-sent events, commands by POST. No framework, no CDN.
'use strict';

const token = new URLSearchParams(location.search).get('token');
const withToken = (path) => token ? `${path}?token=${encodeURIComponent(token)}` : path;
let state = null;
let tab = 'mission';

// ---------- small helpers ----------
function el(tag, attrs, ...children) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) {
    if (v === undefined || v === null || v === false) continue;
    if (k === 'class') e.className = v;
    else if (k === 'text') e.textContent = v;
    else if (k.startsWith('on')) e.addEventListener(k.slice(2), v);
    else e.setAttribute(k, v === true ? '' : String(v));
  }
  for (const c of children.flat(Infinity)) {
    if (c === null || c === undefined) continue;
    e.append(c instanceof Node ? c : document.createTextNode(String(c)));
  }
  return e;
}
const fmt = (x, d = 1) => (typeof x === 'number' && isFinite(x)) ? x.toFixed(d) : '—';
const $ = (id) => document.getElementById(id);
function badge(kind, text) { return el('span', { class: `badge ${kind}`, text }); }

function say(text, ok) {
  const m = $('message');
  m.textContent = text;
  m.className = ok ? 'ok' : 'error';
}

async function command(cmd) {
  try {
    const r = await fetch(withToken('/api/command'), {
      method: 'POST',
      headers: { 'content-type': 'application/json' },
      body: JSON.stringify(cmd),
    });
    let reply;
    try { reply = await r.json(); } catch (_) { reply = { ok: false, message: `the server answered ${r.status}` }; }
    say(reply.message, reply.ok);
    return reply.ok;
  } catch (e) {
    say(`the console's server cannot be reached (${e.message}); the robots keep their last orders`, false);
    return false;
  }
}

function fleetStop() { command({ cmd: 'stop', reason: 'operator (console)' }); }

// ---------- tabs and keys ----------
for (const b of document.querySelectorAll('nav [role=tab]')) {
  b.addEventListener('click', () => showTab(b.dataset.tab));
}
function showTab(name) {
  tab = name;
  for (const b of document.querySelectorAll('nav [role=tab]')) b.setAttribute('aria-selected', String(b.dataset.tab === name));
  for (const s of document.querySelectorAll('section.tab')) s.hidden = s.id !== `tab-${name}`;
  if (state) render(state);
}
document.addEventListener('keydown', (ev) => {
  const typing = ['INPUT', 'SELECT', 'TEXTAREA'].includes(document.activeElement?.tagName);
  if (ev.key === 'Escape' || (ev.key === ' ' && !typing && document.activeElement?.tagName !== 'BUTTON')) {
    ev.preventDefault();
    fleetStop();
  }
});
$('stop').addEventListener('click', fleetStop);
$('resume').addEventListener('click', () => command({ cmd: 'resume' }));
$('add-form').addEventListener('submit', async (ev) => {
  ev.preventDefault();
  const input = $('add-colour');
  if (await command({ cmd: 'add', target: input.value })) input.value = '';
});
$('log-filter').addEventListener('input', () => state && renderLog(state));
$('log-kind').addEventListener('change', () => state && renderLog(state));

// ---------- live feed ----------
function connect() {
  const es = new EventSource(withToken('/api/events'));
  es.addEventListener('state', (ev) => {
    $('link').textContent = 'live';
    $('link').className = 'badge life-alive';
    try { state = JSON.parse(ev.data); } catch (_) { return; }
    render(state);
  });
  es.onerror = () => {
    $('link').textContent = 'reconnecting…';
    $('link').className = 'badge life-lost';
  };
}

// ---------- rendering ----------
function render(s) {
  $('clock').textContent = `mission ${fmt(s.t_s)} s${s.over ? ' · over' : ''}`;
  const f = $('fleet');
  f.textContent = s.fleet_stopped ? 'fleet: STOPPED' : 'fleet: running';
  f.className = `badge ${s.fleet_stopped ? 'life-lost' : 'life-alive'}`;
  renderMission(s);
  if (tab === 'map') renderMap(s);
  if (tab === 'peer') renderPeer(s);
  if (tab === 'san') renderSan(s);
}

function renderMission(s) {
  const dl = $('colours');
  if (dl.childElementCount !== s.colours.length) dl.replaceChildren(...s.colours.map((c) => el('option', { value: c })));
  const body = $('targets').tBodies[0];
  const rows = s.targets.map((t, i) => {
    const st = t.state || 'unknown';
    const open = st !== 'done' && st !== 'failed';
    const note = t.cancelled ? ' (cancelled)' : t.given_up ? ' (given up)' : '';
    const actions = el('td', {},
      st === 'waiting' && i > 0 && s.targets[i - 1].state === 'waiting'
        ? el('button', { class: 'up', title: 'move up', 'aria-label': `move ${t.target} up`, onclick: () => command({ cmd: 'move', from: i, to: i - 1 }) }, '▲') : null,
      st === 'waiting' && i + 1 < s.targets.length && s.targets[i + 1].state === 'waiting'
        ? el('button', { class: 'down', title: 'move down', 'aria-label': `move ${t.target} down`, onclick: () => command({ cmd: 'move', from: i, to: i + 1 }) }, '▼') : null,
      open && !s.over ? el('button', { class: 'cancel', 'aria-label': `cancel ${t.target}`, onclick: () => command({ cmd: 'cancel', target: t.target }) }, 'Cancel') : null);
    return el('tr', { class: 'target', 'data-target': t.target, 'data-index': i, 'data-state': st },
      el('td', { class: 'num', text: i + 1 }),
      el('td', { text: t.target }),
      el('td', { class: 'state' }, badge(`state-${st}`, st + note)),
      el('td', { class: 'num', text: fmt(t.time_s) }),
      el('td', { class: 'num', text: fmt(t.performance, 2) }),
      actions);
  });
  // Keep the focused button across renders only when nothing changed.
  const key = JSON.stringify(s.targets) + s.over;
  if (body.dataset.key !== key) { body.replaceChildren(...rows); body.dataset.key = key; }
  $('no-targets').hidden = s.targets.length > 0;

  const robots = Object.entries(s.robots).map(([name, r]) => {
    const life = r.life || 'unknown';
    return el('div', { class: 'card robot', 'data-robot': name },
      el('h3', {}, name, ' ', badge(`life-${life === 'unknown' ? 'unknown state-unknown' : life}`, life), r.halted ? ' ' : null, r.halted ? badge('state-failed', 'halted') : null),
      el('dl', {},
        el('dt', { text: 'behaviour' }), el('dd', { class: 'behaviour', text: r.behaviour || '—' }),
        el('dt', { text: 'last heard' }), el('dd', { text: r.last_t_s == null ? '—' : `${fmt(r.last_t_s)} s` }),
        life === 'lost' ? el('dt', { text: 'silent' }) : null, life === 'lost' ? el('dd', { text: `${fmt(r.silent_s)} s` }) : null,
        el('dt', { text: 'pose' }), el('dd', { text: r.pose ? `${fmt(r.pose[0], 2)}, ${fmt(r.pose[1], 2)} m` : '—' })));
  });
  $('robots').replaceChildren(...robots);

  $('notices').replaceChildren(...s.notices.slice().reverse().slice(0, 6).map((n) =>
    el('li', { class: `notice-${n.level}` }, `[${fmt(n.t_s)} s] ${n.level === 'error' ? 'refused: ' : ''}${n.text}`)));
  renderLog(s);
  renderSummary(s);
}

function renderLog(s) {
  const q = $('log-filter').value.trim().toLowerCase();
  const kind = $('log-kind').value;
  const lines = [];
  for (let i = s.log.length - 1; i >= 0 && lines.length < 200; i--) {
    const l = s.log[i];
    if (kind && l.kind !== kind) continue;
    const text = `[${fmt(l.t_s)} s] ${l.robot} ${l.kind}: ${l.text}`;
    if (q && !text.toLowerCase().includes(q)) continue;
    lines.push(el('li', { class: `k-${l.kind}`, value: l.seq, text }));
  }
  $('log').replaceChildren(...lines);
}

function renderSummary(s) {
  const box = $('summary');
  if (!s.summary) { box.hidden = true; return; }
  box.hidden = false;
  const sm = s.summary;
  const key = JSON.stringify(sm);
  if (box.dataset.key === key) return;
  box.dataset.key = key;
  box.replaceChildren(
    el('strong', {}, `Mission over: ${sm.done} done, ${sm.failed} failed; mission time ${fmt(sm.mission_time_s)} s, Scooter drove ${fmt(sm.scooter_distance_m, 2)} m.`),
    ' ', el('span', { class: 'muted', text: 'Trajectories: see the Map. Ctrl-C in the terminal ends the console.' }));
}

// ---------- map ----------
function renderMap(s) {
  const c = $('map');
  const w = c.clientWidth || 800;
  if (c.width !== w) { c.width = w; c.height = Math.round(w * 0.7); }
  const g = c.getContext('2d');
  g.clearRect(0, 0, c.width, c.height);
  const xs = [], ys = [];
  const add = (p) => { if (p && isFinite(p[0]) && isFinite(p[1])) { xs.push(p[0]); ys.push(p[1]); } };
  const world = s.world;
  if (world) {
    for (const [a, b] of world.walls) { add(a); add(b); }
    for (const o of world.objects) add(o.center);
  }
  for (const r of Object.values(s.robots)) { add(r.pose); add(r.truth); r.trail.forEach(add); r.truth_trail.forEach(add); }
  if (!xs.length) { xs.push(-3, 3); ys.push(-3, 3); }
  const pad = 0.8;
  const x0 = Math.min(...xs) - pad, x1 = Math.max(...xs) + pad, y0 = Math.min(...ys) - pad, y1 = Math.max(...ys) + pad;
  const k = Math.min(c.width / (x1 - x0), c.height / (y1 - y0));
  const px = (x) => (x - x0) * k, py = (y) => c.height - (y - y0) * k;
  // 1 m grid
  g.strokeStyle = '#e6e6e6'; g.lineWidth = 1;
  for (let x = Math.ceil(x0); x <= x1; x++) { g.beginPath(); g.moveTo(px(x), 0); g.lineTo(px(x), c.height); g.stroke(); }
  for (let y = Math.ceil(y0); y <= y1; y++) { g.beginPath(); g.moveTo(0, py(y)); g.lineTo(c.width, py(y)); g.stroke(); }
  if (world) {
    g.strokeStyle = '#333'; g.lineWidth = 3;
    for (const [a, b] of world.walls) { g.beginPath(); g.moveTo(px(a[0]), py(a[1])); g.lineTo(px(b[0]), py(b[1])); g.stroke(); }
    g.fillStyle = '#aaa';
    for (const ci of world.circles) { g.beginPath(); g.arc(px(ci.center[0]), py(ci.center[1]), ci.radius_m * k, 0, 7); g.fill(); }
    for (const o of world.objects) {
      g.fillStyle = `rgb(${o.rgb.join(',')})`; g.strokeStyle = '#222'; g.lineWidth = 1;
      g.beginPath(); g.arc(px(o.center[0]), py(o.center[1]), Math.max(o.radius_m * k, 4), 0, 7); g.fill(); g.stroke();
      g.fillStyle = '#222'; g.font = '12px sans-serif'; g.fillText(o.color, px(o.center[0]) + 8, py(o.center[1]) - 8);
    }
  }
  const palette = { skeeter: '#1f77b4', scooter: '#d62728' };
  const line = (pts, colour, alpha, dash) => {
    if (pts.length < 2) return;
    g.save(); g.globalAlpha = alpha; g.strokeStyle = colour; g.lineWidth = 2; g.setLineDash(dash);
    g.beginPath(); g.moveTo(px(pts[0][0]), py(pts[0][1]));
    for (const p of pts.slice(1)) g.lineTo(px(p[0]), py(p[1]));
    g.stroke(); g.restore();
  };
  const drawn = [];
  const robotAt = (p, colour, alpha, label) => {
    g.save(); g.globalAlpha = alpha; g.fillStyle = colour; g.strokeStyle = colour; g.lineWidth = 2;
    g.beginPath(); g.arc(px(p[0]), py(p[1]), Math.max(0.25 * k, 5), 0, 7); g.fill();
    g.beginPath(); g.moveTo(px(p[0]), py(p[1])); g.lineTo(px(p[0] + 0.6 * Math.cos(p[2])), py(p[1] + 0.6 * Math.sin(p[2]))); g.stroke();
    if (label) { g.fillStyle = '#111'; g.font = 'bold 13px sans-serif'; g.fillText(label, px(p[0]) + 9, py(p[1]) + 16); }
    g.restore();
  };
  for (const [name, r] of Object.entries(s.robots)) {
    const colour = palette[name] || '#6a1b9a';
    line(r.truth_trail, colour, 0.25, [4, 4]);
    line(r.trail, colour, 0.9, []);
    if (r.truth) robotAt(r.truth, colour, 0.25, null);
    const p = r.pose || r.truth;
    if (p) { robotAt(p, colour, 1, name); drawn.push(name); }
  }
  // Skeeter's SES: a ray per bearing from where Skeeter is; where a range is known, a solid
  // segment to that range and a dot at the object's estimated place.
  const sk = s.robots.skeeter;
  const skp = sk && (sk.pose || sk.truth);
  const sesDrawn = [];
  if (s.ses && skp) {
    g.save(); g.lineWidth = 1.5;
    for (const r of s.ses.form.records) {
      const a = skp[2] + r.bearing_rad;
      const ranged = typeof r.range_m === 'number' && isFinite(r.range_m) && r.range_m >= 0;
      const len = ranged ? r.range_m : 3;
      const colour = r.object === 'scooter' ? '#d62728' : '#2e7d32';
      const ex = skp[0] + len * Math.cos(a), ey = skp[1] + len * Math.sin(a);
      g.strokeStyle = colour; g.setLineDash(ranged ? [] : [6, 4]);
      g.beginPath(); g.moveTo(px(skp[0]), py(skp[1])); g.lineTo(px(ex), py(ey)); g.stroke();
      if (ranged) {
        g.fillStyle = colour; g.beginPath(); g.arc(px(ex), py(ey), 5, 0, 7); g.fill();
      }
      g.fillStyle = '#333'; g.font = '11px sans-serif';
      g.fillText(`${r.object}${ranged ? ` ${fmt(r.range_m)} m` : ''}`, px(ex) + 6, py(ey) + 16);
      sesDrawn.push({ object: r.object, bearing: r.bearing_rad, range: ranged ? r.range_m : null, at: ranged ? [ex, ey] : null });
    }
    g.restore();
  }
  $('map-ses').replaceChildren(...(sesDrawn.length
    ? sesDrawn.map((r) => el('li', {
      class: 'ses-mark', 'data-object': r.object, 'data-ranged': r.range != null ? 'yes' : 'no',
      text: `${r.object}: bearing ${fmt(r.bearing * 180 / Math.PI, 0)}°${r.range != null ? `, range ${fmt(r.range, 2)} m (at ${fmt(r.at[0], 2)}, ${fmt(r.at[1], 2)})` : ', no range (bearing only)'}`,
    }))
    : [el('li', { class: 'muted', text: s.ses ? 'Skeeter\'s place is not known yet: its SES cannot be drawn.' : 'No SES from Skeeter yet.' })]));
  // Scooter's computed heading, plan and laser obstacles (its DR frame, drawn from its start).
  const sc = s.robots.scooter, m = s.scooter_map;
  if (sc && m && sc.pose) {
    const ox = sc.pose[0] - m.dr[0], oy = sc.pose[1] - m.dr[1];
    g.fillStyle = '#555';
    for (const o of m.obstacles) g.fillRect(px(o[0] + ox) - 1.5, py(o[1] + oy) - 1.5, 3, 3);
    if (typeof m.desired_rad === 'number') {
      g.save(); g.strokeStyle = '#ff8f00'; g.lineWidth = 3;
      g.beginPath(); g.moveTo(px(sc.pose[0]), py(sc.pose[1]));
      g.lineTo(px(sc.pose[0] + 1.2 * Math.cos(m.desired_rad)), py(sc.pose[1] + 1.2 * Math.sin(m.desired_rad))); g.stroke(); g.restore();
    }
    if (m.plan && m.plan.point) {
      g.strokeStyle = '#ff8f00'; g.lineWidth = 2;
      const q = [m.plan.point[0] + ox, m.plan.point[1] + oy];
      g.beginPath(); g.moveTo(px(q[0]) - 6, py(q[1]) - 6); g.lineTo(px(q[0]) + 6, py(q[1]) + 6);
      g.moveTo(px(q[0]) + 6, py(q[1]) - 6); g.lineTo(px(q[0]) - 6, py(q[1]) + 6); g.stroke();
    }
  }
  $('map-legend').textContent = 'Solid: each robot\'s belief and trail; faint dashed: ground truth (simulated world); '
    + 'Skeeter\'s SES: dashed rays for bearings only, solid segments with a dot where a range is known; orange: Scooter\'s desired heading and plan; grey dots: laser obstacles; grid 1 m.';
  const missing = Object.keys(s.robots).filter((n) => !drawn.includes(n)).sort();
  $('map-missing').textContent = missing.length ? `No pose from ${missing.join(', ')} yet: not drawn.` : '';
  $('map-robots').replaceChildren(...drawn.map((n) => {
    const r = s.robots[n];
    const plan = n === 'scooter' && m ? `; heading ${fmt(m.heading_rad == null ? NaN : m.heading_rad * 180 / Math.PI, 0)}°, desired ${fmt(m.desired_rad == null ? NaN : m.desired_rad * 180 / Math.PI, 0)}°` : '';
    const p = r.pose || r.truth;
    return el('li', { class: 'map-robot', 'data-robot': n, text: `${n}: ${fmt(p[0], 2)}, ${fmt(p[1], 2)} m${plan}` });
  }));
}

// ---------- Peer Agents ----------
function refused(r) {
  if (!r) return '—';
  return `auth failures ${r.auth_failures ?? r.bad_mac ?? 0}, bad frames ${r.bad_frames ?? 0}, replayed ${r.replayed ?? r.replay ?? 0}`;
}
// One link's health: heartbeats both ways, frames, last seen (numbers in their own spans).
function health(l) {
  const n = (cls, v) => el('span', { class: `num ${cls}`, text: String(v) });
  return ['heartbeats in ', n('hb-rx', l.heartbeats_received), ', out ', n('hb-tx', l.heartbeats_sent),
    '; frames in ', n('frames', l.frames_received), '; last seen ', n('last-seen', l.last_seen_ms), ' ms ago'];
}
function renderPeer(s) {
  const names = new Set([...Object.keys(s.peer), ...Object.keys(s.peer_events)]);
  // Robots heard on the broadcast channel whose Peer Agent runs in another process.
  for (const [n, r] of Object.entries(s.robots)) if (r.life || r.last_t_s != null) names.add(n);
  const cards = [...names].sort().map((name) => {
    const p = s.peer[name] || {};
    if (!s.peer[name] && !s.peer_events[name]) {
      const r = s.robots[name];
      return el('div', { class: 'card peer remote', 'data-robot': name }, el('h3', { text: name }),
        el('dl', {}, el('dt', { text: 'link' }), el('dd', {}, r.life ? badge(`life-${r.life}`, r.life) : '—', r.last_t_s != null ? ` last heard ${fmt(r.last_t_s)} s` : '')),
        el('p', { class: 'muted no-data', text: 'No Peer Agent status from this robot here: it runs in a process of its own (ima run), and only its broadcasts (liveness, behaviour, pose) reach this console. Its manager\'s sources, clients and link health are on its own console.' }));
    }
    const b = p.broadcast;
    const r = s.robots[name];
    const parts = [
      el('h3', { text: name }),
      el('dl', {},
        el('dt', { text: 'link' }), el('dd', {}, r && r.life ? badge(`life-${r.life}`, r.life) : '—', r && r.last_t_s != null ? ` last heard ${fmt(r.last_t_s)} s` : ''),
        p.address ? [el('dt', { text: 'manager' }), el('dd', { text: p.address })] : null,
        b ? [el('dt', { text: 'broadcasts' }), el('dd', { text: `sent ${b.sent}, accepted ${b.accepted}, duplicate ${b.duplicate}, stale ${b.stale}, send errors ${b.send_errors}` }),
          el('dt', { text: 'broadcasts refused' }), el('dd', { class: 'refused', text: refused(b.rejected) })] : null,
        p.sessions != null ? [el('dt', { text: 'sessions' }), el('dd', { text: `${p.sessions} request, ${p.data_sessions} data; lost ${p.lost}, closed bad ${p.closed_bad}, slow closed ${p.slow_closed}` }),
          el('dt', { text: 'manager refused' }), el('dd', { class: 'refused', text: `${refused(p.rejected)}; data sessions: ${refused(p.data_rejected)}, bad tickets ${p.data_bad_tickets}` })] : null),
    ];
    if (p.sources && p.sources.length) {
      parts.push(el('h4', { text: 'sources' }), el('ul', {}, p.sources.map((x) => el('li', { text: `${x.name} (${x.kind}, ${x.rate_mhz / 1000} Hz)` }))));
    }
    if (p.links) {
      parts.push(el('h4', { text: 'link health (request-channel sessions)' }), p.links.length
        ? el('ul', {}, p.links.map((l) => el('li', { class: 'link', 'data-addr': l.addr },
          el('b', { text: `${l.robots.join(', ') || '(not registered)'} ` }), el('span', { class: 'muted', text: `from ${l.addr}: ` }), ...health(l))))
        : el('p', { class: 'muted', text: 'no session open' }));
    }
    if (p.clients) {
      parts.push(el('h4', { text: 'clients, requests and grants' }), p.clients.length
        ? el('ul', {}, p.clients.map((c) => {
          const reqs = (c.requests || []).map((q) => `${q.source} (priority robot ${q.robot_priority}, request ${q.request_priority}) ${q.granted ? 'granted' : 'pending'}`);
          const recent = (c.recent || []).slice(-4).map((d) => `${d.source}: ${d.outcome}`);
          return el('li', { class: 'client' },
            el('div', { text: `${c.robot} #${c.client}${c.session ? ` from ${c.session}` : ''}: ${reqs.length ? reqs.join('; ') : 'no request'}` }),
            recent.length ? el('div', { class: 'muted', text: `latest decisions: ${recent.join(', ')}` }) : null);
        }))
        : el('p', { class: 'muted', text: 'no client' }));
    }
    const c = p.client;
    if (c) {
      const l = c.link;
      parts.push(el('h4', { text: 'as a client' }),
        el('p', { class: 'client-sub', text: `subscribes ${c.source} at ${c.manager} with request priority ${c.priority}: ${c.outcome}; grants ${c.grants}, samples ${c.samples}, retries ${c.retries}` }),
        l ? el('p', { class: 'link client-link' }, el('b', { text: `${l.registration} ` }), ...health(l), `; refused: ${refused(l.rejected)}`)
          : el('p', { class: 'muted', text: 'no session open now' }));
    }
    const evs = s.peer_events[name] || [];
    if (evs.length) {
      parts.push(el('h4', { text: 'Peer Agent events (requests, grants, losses, retries)' }), el('ul', {}, evs.slice(-8).reverse().map((e) =>
        el('li', { text: `[${fmt(e.t_s)} s] ${e.kind} ${JSON.stringify(e.detail)}` }))));
    }
    return el('div', { class: 'card peer', 'data-robot': name }, parts);
  });
  $('peer').replaceChildren(...(cards.length ? cards : [el('p', { class: 'muted', text: 'No Peer Agent status yet.' })]));
}

// ---------- SAN ----------
const chartColours = ['#1f77b4', '#d62728', '#2ca02c', '#9467bd', '#ff7f0e', '#8c564b', '#e377c2', '#17becf', '#7f7f7f', '#bcbd22'];
function renderSan(s) {
  const names = new Set([...Object.keys(s.san)]);
  for (const [n, r] of Object.entries(s.robots)) if (r.san_summary) names.add(n);
  const cards = [...names].sort().map((name) => {
    const v = s.san[name];
    const r = s.robots[name] || {};
    if (!v) {
      return el('div', { class: 'card san', 'data-robot': name }, el('h3', { text: name }),
        el('p', {}, `behaviour ${r.behaviour || '—'}; true conditions: ${r.san_summary || '—'}`),
        el('p', { class: 'muted no-data', text: 'No activations from this robot here: it runs in a process of its own (ima run) and its broadcasts carry only its behaviour and true conditions. Activations are charted for robots run by this process (ima demo).' }));
    }
    const L = v.latest;
    const modules = L.modules || [];
    const canvas = el('canvas', { class: 'chart', width: 600, height: 120, 'aria-label': `${name} activations over time` });
    const most = Math.max(1e-9, ...modules.map((m) => m.activation || 0));
    const rows = modules.map((m, i) => el('tr', { class: m.name === L.selected ? 'selected module' : 'module', 'data-module': m.name },
      el('td', {}, el('span', { class: 'bar', style: `width:${Math.round(60 * Math.max(0, m.activation || 0) / most)}px;background:${chartColours[i % chartColours.length]}` })),
      el('td', { text: m.name }),
      el('td', { class: 'act num', text: fmt(m.activation, 3) }),
      el('td', {}, badge(`flag-${m.executable}`, m.executable ? 'executable' : 'not executable'))));
    const card = el('div', { class: 'card san', 'data-robot': name },
      el('h3', {}, `${name} `, el('span', { class: 'muted', text: L.network || '' })),
      el('p', {}, 'selected ', el('strong', { class: 'selected-behaviour', text: L.selected || '—' }), ` · threshold θ ${fmt(L.threshold, 3)}`),
      canvas,
      el('div', { class: 'scroll' }, el('table', {}, el('thead', {}, el('tr', {}, el('th', {}), el('th', { text: 'module' }), el('th', { text: 'activation' }), el('th', { text: 'flags' }))), el('tbody', {}, rows))),
      el('h4', { text: 'conditions' }),
      el('p', {}, (L.conditions || []).map((c) => [badge(`flag-${c.value}`, `${c.name} ${c.value ? 'true' : 'false'}`), ' '])));
    drawChart(canvas, v.history, modules.length, L.threshold);
    return card;
  });
  $('san').replaceChildren(...(cards.length ? cards : [el('p', { class: 'muted', text: 'No SAN state yet.' })]));
}
function drawChart(c, hist, n, theta) {
  const g = c.getContext('2d');
  g.clearRect(0, 0, c.width, c.height);
  if (hist.length < 2) return;
  const t0 = hist[0][0], t1 = hist[hist.length - 1][0];
  let top = Math.max(theta || 0, 0.1);
  for (const [, a] of hist) for (const x of a) if (x > top) top = x;
  const px = (t) => (t1 > t0 ? (t - t0) / (t1 - t0) : 0) * (c.width - 4) + 2;
  const py = (a) => c.height - 4 - (a / top) * (c.height - 8);
  if (theta) { g.strokeStyle = '#999'; g.setLineDash([4, 4]); g.beginPath(); g.moveTo(0, py(theta)); g.lineTo(c.width, py(theta)); g.stroke(); g.setLineDash([]); }
  for (let i = 0; i < n; i++) {
    g.strokeStyle = chartColours[i % chartColours.length]; g.lineWidth = 1.5; g.beginPath();
    hist.forEach(([t, a], j) => { const y = py(a[i] || 0); if (j) g.lineTo(px(t), y); else g.moveTo(px(t), y); });
    g.stroke();
  }
}

window.addEventListener('resize', () => state && tab === 'map' && renderMap(state));
connect();
