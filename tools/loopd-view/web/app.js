// loopd-view page: draws the newest state the server pushed over /events (server-sent events).
// Stale states are never drawn: each SSE message replaces the pending one, and one
// requestAnimationFrame callback parses and draws only the newest. After each drawing the
// body's data-* attributes say what was drawn (tests read them).
'use strict';
(() => {
  const $ = (id) => document.getElementById(id);
  const canvas = $('map');
  const ctx = canvas.getContext('2d');
  const body = document.body;

  let pending = null;    // newest SSE payload (string), not yet parsed
  let state = null;      // the state being shown
  let frameQueued = false;
  const stats = { received: 0, drawn: 0, skipped: 0, parseMs: 0, drawMs: 0, bytes: 0 };
  const view = { auto: true, scale: 1, cx: 0, cy: 0 };  // scale: px per metre; (cx, cy) at the centre
  let plane = 'xy';
  const show = { links: true, accepted: true, ellipses: true, landmarks: true };

  // ---- data in -------------------------------------------------------------------------------
  function connect() {
    const es = new EventSource('/events');
    es.addEventListener('state', (e) => {
      if (pending !== null) stats.skipped++;  // never drawn: a newer one arrived first
      pending = e.data;
      stats.received++;
      stats.bytes = e.data.length;
      queueFrame();
    });
    es.onopen = () => setConn('ok', 'live');
    es.onerror = () => setConn('bad', 'disconnected — retrying');
  }
  function setConn(cls, text) {
    const c = $('conn');
    c.className = 'conn ' + cls;
    c.textContent = text;
    body.dataset.connection = cls;
  }
  function queueFrame() {
    if (frameQueued) return;
    frameQueued = true;
    requestAnimationFrame(frame);
  }
  function frame() {
    frameQueued = false;
    if (pending !== null) {
      const t0 = performance.now();
      try {
        state = JSON.parse(pending);
      } catch (err) {
        console.error('bad state', err);
      }
      pending = null;
      stats.parseMs = performance.now() - t0;
      updatePanel();
    }
    draw();
  }

  // ---- geometry ------------------------------------------------------------------------------
  const axes = { xy: [0, 1], xz: [0, 2], yz: [1, 2] };
  // Projected (u, v) of point i of a flat array with dimension d (2D maps have z = 0).
  function proj(p, d, i, out) {
    const [a, b] = axes[plane];
    out[0] = a < d ? p[i * d + a] : 0;
    out[1] = b < d ? p[i * d + b] : 0;
    return out;
  }
  // Robot colours stay clear of the links' green (accepted) and red (rejected).
  const palette = [[31, 119, 180], [255, 127, 14], [148, 103, 189], [140, 86, 75], [227, 119, 194],
    [23, 190, 207], [188, 189, 34], [57, 59, 121], [127, 127, 127], [82, 84, 163]];
  function colour(robotId, alpha) {
    if (robotId >= 0 && robotId < palette.length) {
      const [r, g, b] = palette[robotId];
      return `rgba(${r}, ${g}, ${b}, ${alpha})`;
    }
    let h = (robotId * 137.508) % 360;  // skip the reds (330..30) and greens (90..160)
    if (h < 30 || h >= 330) h = (h + 60) % 360;
    if (h >= 90 && h < 160) h += 70;
    return `hsla(${h.toFixed(1)}, 65%, ${robotId % 2 ? 38 : 48}%, ${alpha})`;
  }
  function size() {
    const dpr = window.devicePixelRatio || 1;
    const w = canvas.clientWidth, h = canvas.clientHeight;
    if (canvas.width !== Math.round(w * dpr) || canvas.height !== Math.round(h * dpr)) {
      canvas.width = Math.round(w * dpr);
      canvas.height = Math.round(h * dpr);
    }
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    return [w, h];
  }
  function fit(w, h) {
    let minU = Infinity, minV = Infinity, maxU = -Infinity, maxV = -Infinity;
    const q = [0, 0];
    for (const r of state.robots) {
      const n = r.p.length / r.d;
      for (let i = 0; i < n; i++) {
        proj(r.p, r.d, i, q);
        if (q[0] < minU) minU = q[0];
        if (q[0] > maxU) maxU = q[0];
        if (q[1] < minV) minV = q[1];
        if (q[1] > maxV) maxV = q[1];
      }
    }
    if (!isFinite(minU)) return;
    const spanU = Math.max(maxU - minU, 1e-3), spanV = Math.max(maxV - minV, 1e-3);
    view.scale = Math.min((w - 40) / spanU, (h - 40) / spanV);
    if (!isFinite(view.scale) || view.scale <= 0) view.scale = 1;
    view.cx = (minU + maxU) / 2;
    view.cy = (minV + maxV) / 2;
  }

  // ---- drawing -------------------------------------------------------------------------------
  function draw() {
    const t0 = performance.now();
    const [w, h] = size();
    ctx.fillStyle = '#ffffff';
    ctx.fillRect(0, 0, w, h);
    const counts = { poses: 0, robots: 0, accepted: 0, rejected: 0, undecided: 0, ellipses: 0, landmarks: 0 };
    if (!state || !state.robots || state.robots.length === 0) {
      ctx.fillStyle = '#7a8394';
      ctx.font = '15px system-ui, sans-serif';
      ctx.textAlign = 'center';
      ctx.fillText(state && state.status ? 'server up, no poses yet' : 'waiting for a loopd server…', w / 2, h / 2);
      publish(counts);
      return;
    }
    if (view.auto) fit(w, h);
    const s = view.scale, cx = view.cx, cy = view.cy, w2 = w / 2, h2 = h / 2;
    const X = (u) => w2 + (u - cx) * s;
    const Y = (v) => h2 - (v - cy) * s;
    const q = [0, 0];
    drawScaleBar(w, h, s);

    const byId = new Map();
    for (const r of state.robots) byId.set(r.id, r);

    // Loop closures under the trajectories; rejected ones last so they stay visible.
    if (show.links && state.links) {
      const paths = [new Path2D(), new Path2D(), new Path2D()];  // rejected, accepted, undecided
      const q2 = [0, 0];
      for (const l of state.links) {
        const ra = byId.get(l[0]), rb = byId.get(l[2]);
        if (!ra || !rb) continue;
        const st = l[4];
        if (st === 1 && !show.accepted) { counts.accepted++; continue; }
        proj(ra.p, ra.d, l[1], q);
        proj(rb.p, rb.d, l[3], q2);
        const p = paths[st === 0 ? 0 : st === 1 ? 1 : 2];
        p.moveTo(X(q[0]), Y(q[1]));
        p.lineTo(X(q2[0]), Y(q2[1]));
        if (st === 0) counts.rejected++;
        else if (st === 1) counts.accepted++;
        else counts.undecided++;
      }
      ctx.lineWidth = 1;
      ctx.setLineDash([]);
      ctx.strokeStyle = 'rgba(154,163,178,0.55)';
      ctx.stroke(paths[2]);
      ctx.strokeStyle = 'rgba(46,158,79,0.55)';
      ctx.stroke(paths[1]);
      ctx.save();
      ctx.lineWidth = 1.6;
      ctx.setLineDash([5, 3]);
      ctx.strokeStyle = 'rgba(214,39,40,0.9)';
      ctx.stroke(paths[0]);
      ctx.restore();
    }

    // Trajectories (dashed while a robot is only in its own frame, unlike the others).
    for (const r of state.robots) {
      const n = r.p.length / r.d;
      if (n === 0) continue;
      counts.robots++;
      ctx.beginPath();
      for (let i = 0; i < n; i++) {
        proj(r.p, r.d, i, q);
        if (i === 0) ctx.moveTo(X(q[0]), Y(q[1]));
        else ctx.lineTo(X(q[0]), Y(q[1]));
      }
      counts.poses += n;
      ctx.lineWidth = 1.4;
      ctx.setLineDash(r.common || state.robots.length < 2 ? [] : [6, 4]);
      ctx.strokeStyle = colour(r.id, 0.95);
      ctx.stroke();
      ctx.setLineDash([]);
      // start: ring; latest pose: dot.
      proj(r.p, r.d, 0, q);
      ctx.beginPath();
      ctx.arc(X(q[0]), Y(q[1]), 4, 0, 2 * Math.PI);
      ctx.lineWidth = 1.5;
      ctx.stroke();
      proj(r.p, r.d, n - 1, q);
      ctx.beginPath();
      ctx.arc(X(q[0]), Y(q[1]), 3.5, 0, 2 * Math.PI);
      ctx.fillStyle = colour(r.id, 1);
      ctx.fill();
      if (r.heading !== null && plane === 'xy') {
        ctx.beginPath();
        ctx.moveTo(X(q[0]), Y(q[1]));
        ctx.lineTo(X(q[0]) + 11 * Math.cos(r.heading), Y(q[1]) - 11 * Math.sin(r.heading));
        ctx.strokeStyle = colour(r.id, 1);
        ctx.stroke();
      }
      if (show.landmarks && r.l.length) {
        ctx.fillStyle = colour(r.id, 0.8);
        const m = r.l.length / r.d;
        for (let i = 0; i < m; i++) {
          proj(r.l, r.d, i, q);
          ctx.fillRect(X(q[0]) - 2, Y(q[1]) - 2, 4, 4);
        }
        counts.landmarks += m;
      }
    }

    // 2σ ellipses of each robot's latest pose (position block, projected on the plane).
    if (show.ellipses && state.covariances) {
      const pick = { xy: [0, 1, 3], xz: [0, 2, 5], yz: [3, 4, 5] }[plane];
      const [a0, b0] = axes[plane];
      for (const c of state.covariances) {
        const a = c.c[pick[0]], b = c.c[pick[1]], d = c.c[pick[2]];
        if (![a, b, d].every(Number.isFinite)) continue;
        const m = (a + d) / 2, r = Math.sqrt(((a - d) / 2) ** 2 + b * b);
        const l1 = Math.max(m + r, 0), l2 = Math.max(m - r, 0);
        const ang = 0.5 * Math.atan2(2 * b, a - d);
        const rx = Math.max(2 * Math.sqrt(l1) * s, 1.5), ry = Math.max(2 * Math.sqrt(l2) * s, 1.5);
        ctx.beginPath();
        ctx.ellipse(X(c.pos[a0]), Y(c.pos[b0]), rx, ry, -ang, 0, 2 * Math.PI);
        ctx.fillStyle = colour(c.robot, 0.14);
        ctx.fill();
        ctx.lineWidth = 1.2;
        ctx.strokeStyle = colour(c.robot, 0.9);
        ctx.stroke();
        counts.ellipses++;
      }
    }
    stats.drawMs = performance.now() - t0;
    publish(counts);
  }

  function drawScaleBar(w, h, s) {
    const target = 120 / s;  // metres in ~120 px
    const p = Math.pow(10, Math.floor(Math.log10(target)));
    const len = [1, 2, 5, 10].map((k) => k * p).filter((v) => v <= target).pop() || p;
    const px = len * s;
    ctx.strokeStyle = '#5b6475';
    ctx.lineWidth = 2;
    ctx.beginPath();
    ctx.moveTo(14, h - 14);
    ctx.lineTo(14 + px, h - 14);
    ctx.stroke();
    ctx.fillStyle = '#5b6475';
    ctx.font = '11px system-ui, sans-serif';
    ctx.textAlign = 'left';
    ctx.fillText(`${+len.toPrecision(3)} m  (${plane})`, 14, h - 20);
  }

  // What was drawn, for people (legend) and for tests (data-* on <body>).
  function publish(c) {
    stats.drawn++;
    const d = body.dataset;
    d.state = state && state.robots && state.robots.length ? 'drawn' : 'empty';
    d.seq = state ? state.seq : 0;
    d.updateSeq = state && state.status ? state.status.update_seq : -1;
    d.posesDrawn = c.poses;
    d.robotsDrawn = c.robots;
    d.linksAccepted = c.accepted;
    d.rejectedLinks = c.rejected;
    d.linksUndecided = c.undecided;
    d.ellipsesDrawn = c.ellipses;
    d.landmarksDrawn = c.landmarks;
    d.serverPoses = state && state.status ? state.status.poses : -1;
    d.serverRejected = state && state.status ? state.status.loop_closures_rejected : -1;
    d.errorsSeen = state && state.errors ? state.errors.count : 0;
    d.framesDrawn = stats.drawn;
    d.framesSkipped = stats.skipped;
    d.plane = plane;
  }

  // ---- panel ---------------------------------------------------------------------------------
  function rows(tbody, list) {
    const tb = $(tbody).tBodies[0];
    while (tb.rows.length > list.length) tb.deleteRow(-1);
    list.forEach(([k, v], i) => {
      const row = tb.rows[i] || tb.insertRow();
      if (row.cells.length === 0) { row.insertCell(); row.insertCell(); }
      if (row.cells[0].textContent !== k) row.cells[0].textContent = k;
      const t = String(v);
      if (row.cells[1].textContent !== t) row.cells[1].textContent = t;
    });
  }
  const fmt = (x, digits = 3) => (x === null || x === undefined ? '—' : typeof x === 'number' ? +x.toPrecision(digits) : x);
  function ago(us) {
    if (!us) return '—';
    const s = Date.now() / 1000 - us / 1e6;
    if (s < 1.5) return 'just now';
    if (s < 120) return `${s.toFixed(0)} s ago`;
    return `${(s / 60).toFixed(0)} min ago`;
  }
  function updatePanel() {
    if (!state) return;
    const st = state.status;
    rows('status-table', st ? [
      ['solver', st.solver + (st.converged ? ' (converged)' : ' (iterating)')],
      ['last update', ago(st.utime)],
      ['update', st.update_seq],
      ['robots (common frame)', `${st.robots} (${st.robots_in_common_frame})`],
      ['poses', st.poses],
      ['landmarks', st.landmarks],
      ['factors', st.factors],
      ['chi²', fmt(st.chi2, 6)],
      ['update ms (last / mean)', `${fmt(st.last_update_ms)} / ${fmt(st.mean_update_ms)}`],
      ['queue depth', st.queue_depth],
      ['batches ok / rejected / dup', `${st.batches_accepted} / ${st.batches_rejected} / ${st.batches_duplicate}`],
      ['batches held / expired', `${st.batches_held} / ${st.batches_expired}`],
      ['senders with gaps', st.sender_gaps],
    ] : [['server', `no status yet on ${state.prefix}STATUS`]]);
    const lc = state.link_counts || {};
    rows('links-table', [
      ['in the graph (server)', st ? st.loop_closures : '—'],
      ['rejected (server)', st ? st.loop_closures_rejected : '—'],
      ['drawn: accepted', lc.accepted],
      ['drawn: rejected', lc.rejected],
      ['seen, not yet accepted (not drawn)', lc.pending],
      ['duplicate batches (ignored)', lc.duplicate_batches],
      ['decisions without endpoints', lc.unmapped_decisions + (lc.unmapped_rejected ? ` (${lc.unmapped_rejected} rejected)` : '')],
    ]);
    const e = state.errors || { count: 0, recent: [], by_code: {} };
    const badge = $('error-count');
    badge.textContent = e.count;
    badge.className = e.count ? 'badge hot' : 'badge';
    const ul = $('errors');
    ul.textContent = '';
    if (!e.recent.length) {
      const li = document.createElement('li');
      li.className = 'muted';
      li.textContent = 'none';
      ul.appendChild(li);
    }
    for (const x of e.recent) {
      const li = document.createElement('li');
      const code = document.createElement('span');
      code.className = 'code';
      code.textContent = x.code;
      li.appendChild(code);
      li.appendChild(document.createTextNode(` ${x.sender || '?'}${x.factor_id >= 0 ? ' #' + x.factor_id : ''}: ${x.reason}`));
      ul.appendChild(li);
    }
    const legend = $('legend');
    legend.textContent = '';
    for (const r of state.robots) {
      const div = document.createElement('div');
      const sw = document.createElement('span');
      sw.className = 'sw';
      sw.style.background = colour(r.id, 1);
      div.appendChild(sw);
      div.appendChild(document.createTextNode(`robot ${r.id}: ${r.p.length / r.d} poses${r.common || state.robots.length < 2 ? '' : ' (own frame)'}`));
      legend.appendChild(div);
    }
    legend.style.display = state.robots.length ? '' : 'none';
    updateViewTable();
  }
  function updateViewTable() {
    rows('view-table', [
      ['states received / drawn', `${stats.received} / ${stats.drawn}`],
      ['stale states skipped', stats.skipped],
      ['last state', `${(stats.bytes / 1024).toFixed(1)} KiB, parse ${stats.parseMs.toFixed(1)} ms, draw ${stats.drawMs.toFixed(1)} ms`],
      ['channels', state ? `${state.prefix}*` : '—'],
      ['last message', state ? ago(state.last_message_us) : '—'],
    ]);
  }
  setInterval(() => { if (state) { updatePanel(); } }, 1000);

  // ---- interaction ---------------------------------------------------------------------------
  let drag = null;
  canvas.addEventListener('wheel', (e) => {
    e.preventDefault();
    const rect = canvas.getBoundingClientRect();
    const mx = e.clientX - rect.left, my = e.clientY - rect.top;
    const w2 = rect.width / 2, h2 = rect.height / 2;
    const u = view.cx + (mx - w2) / view.scale, v = view.cy - (my - h2) / view.scale;
    const k = Math.exp(-e.deltaY * (e.deltaMode === 1 ? 0.05 : 0.0015));
    view.scale = Math.min(Math.max(view.scale * k, 1e-6), 1e7);
    view.cx = u - (mx - w2) / view.scale;  // keep the point under the cursor fixed
    view.cy = v + (my - h2) / view.scale;
    view.auto = false;
    queueFrame();
  }, { passive: false });
  canvas.addEventListener('mousedown', (e) => {
    drag = { x: e.clientX, y: e.clientY };
    canvas.classList.add('dragging');
  });
  window.addEventListener('mousemove', (e) => {
    if (!drag) return;
    view.cx -= (e.clientX - drag.x) / view.scale;
    view.cy += (e.clientY - drag.y) / view.scale;
    drag = { x: e.clientX, y: e.clientY };
    view.auto = false;
    queueFrame();
  });
  window.addEventListener('mouseup', () => { drag = null; canvas.classList.remove('dragging'); });
  const refit = () => { view.auto = true; queueFrame(); };
  canvas.addEventListener('dblclick', refit);
  $('fit').addEventListener('click', refit);
  window.addEventListener('keydown', (e) => { if (e.key === 'f' && e.target === document.body) refit(); });
  $('plane').addEventListener('change', (e) => { plane = e.target.value; refit(); });
  for (const [id, key] of [['show-links', 'links'], ['show-accepted', 'accepted'], ['show-ellipses', 'ellipses'], ['show-landmarks', 'landmarks']])
    $(id).addEventListener('change', (e) => { show[key] = e.target.checked; queueFrame(); });
  new ResizeObserver(queueFrame).observe(canvas);

  // ?plane=xz selects the plane from the URL (handy for links and tests).
  const wanted = new URLSearchParams(location.search).get('plane');
  if (wanted && axes[wanted]) { plane = wanted; $('plane').value = wanted; }

  connect();
  queueFrame();
})();
