// tally preview: a dependency-free page over the server's JSON API and event stream.
//
// Data flow (docs/preview.md):
//   GET /v1/jobs            the job list (every page), polled every 2 s
//   GET /examples/index.json, /examples/NAME.json   bundled specs for the form
//   POST /v1/jobs/validate, POST /v1/jobs            the form
//   GET /v1/jobs/ID         status: spec, plan, stop rule, image size, trace
//   GET /v1/jobs/ID/events  EventSource: progress, state, tile, tiles, end (ids; the
//                           browser resumes with Last-Event-ID after a dropped connection)
//   GET /v1/jobs/ID/tiles/N pixels of a tile named by a `tile` or `tiles` event, fetched
//                           at most every 250 ms (slower as the image converges), coalesced
//   GET /v1/jobs/ID/image.png  instead of tiles for a large image (over LARGE_TILES tiles
//                           or LARGE_PIXELS pixels): the whole image, one request at a
//                           time, at most every 2 s (slower as it converges)
//   DELETE /v1/jobs/ID, POST /v1/jobs/ID/extend      the buttons
//   PATCH /v1/jobs/ID {"priority"}                    the priority control
//   POST /v1/jobs?priority=P (the job's spec)         Requeue a failed or cancelled job
//   GET /v1/workers         the workers panel, cluster mode only (workers.js)
//   GET /v1/session         who am I; 401 when the server wants a token (docs/security.md):
//   POST /v1/session        then the page asks for it once and trades it for an HttpOnly,
//   DELETE /v1/session      SameSite=Strict session cookie (EventSource sends no headers);
//                           logout ends the cookie and the server closes its streams
'use strict';

(() => {
  const $ = (id) => document.getElementById(id);

  const { api, fmtNum, fmtCount, fmtDuration, el } = window.tally;

  // sRGB OETF and 8-bit rounding exactly as the server's PNG encoder
  // (common/image/image_io.cpp): clamp to [0, 1], NaN -> 0, round half away from 0.
  function srgb8(v) {
    if (!(v > 0)) return 0;  // also NaN
    if (v >= 1) return 255;
    const s = v <= 0.0031308 ? 12.92 * v : 1.055 * Math.pow(v, 1 / 2.4) - 0.055;
    return Math.round(255 * s);
  }

  // Above this many tiles or pixels an image is "large": the page draws it from
  // image.png, one request per refresh decoded off the main thread, instead of one
  // JSON request per tile (a 4K frame has 8,160 tiles of 30–130 KB of JSON each), and the
  // standard-error map (which needs the tiles' JSON) is off. docs/preview.md.
  const LARGE_TILES = 1024;
  const LARGE_PIXELS = 1024 * 1024;

  // Perceptual heat ramp (inferno-like), t in [0, 1].
  const RAMP = [[0, 0, 4], [59, 15, 112], [140, 41, 129], [222, 73, 104], [254, 159, 109], [252, 253, 191]];
  function heat(t) {
    t = Math.min(1, Math.max(0, t)) * (RAMP.length - 1);
    const i = Math.min(RAMP.length - 2, Math.floor(t));
    const f = t - i, a = RAMP[i], b = RAMP[i + 1];
    return [a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1]), a[2] + f * (b[2] - a[2])];
  }

  // ------------------------------------------------------------------ test hook
  // Browser tests read what the page saw (pass numbers, tile and image fetches, the
  // image's path and scale) and can drop the event stream; nothing else uses this object.
  const hook = {
    streamClosed: 0,
    streamsOpened: 0,     // EventSources the page created
    loggedIn: false,
    jobId: null,
    passesSeen: [],       // pass of every progress event received, in order
    eventIds: [],         // ids of every event received
    tileFetches: 0,
    tileEvents: 0,
    tilesEvents: 0,       // `tiles` events (one per pass that refined more than 64 tiles)
    imageFetches: 0,      // image.png requests (large images)
    imageDraws: 0,        // image.png answers drawn
    large: false,         // the open job's image is drawn from image.png
    zoom: 'fit',          // 'fit' or '1:1'
    flushes: 0,
    reconnects: 0,
    ended: false,
    settled: false,       // job ended and every announced tile is drawn
    lastEventId: null,
    dropStream: () => view && view.dropStream(),
    // Whether the page holds an event stream that is open or reconnecting.
    streamOpen: () => !!(view && view.es && view.es.readyState !== EventSource.CLOSED),
  };
  window.tallyPreview = hook;

  // ------------------------------------------------------------------ job list

  let selectedId = null;
  let view = null;

  async function refreshJobs() {
    if (!loggedIn) return;
    try {
      // The list comes in pages (submission order); follow each page's `next` link.
      const jobs = [];
      let page = '/v1/jobs?limit=1000';
      for (let n = 0; page && n < 100; n++) {
        const data = await api('GET', page);
        jobs.push(...(data.jobs || []));
        page = typeof data.next === 'string' ? data.next : null;
      }
      $('server-status').textContent = 'server ok';
      $('server-status').classList.remove('down');
      renderJobs(jobs);
    } catch (e) {
      $('server-status').textContent = 'server unreachable';
      $('server-status').classList.add('down');
    }
  }

  function renderJobs(jobs) {
    const tbody = $('jobs').querySelector('tbody');
    tbody.replaceChildren();
    $('jobs-empty').hidden = jobs.length > 0;
    for (const j of jobs.slice().reverse()) {
      // The id's first 8 digits (the whole id in the tooltip and the job view); the name,
      // or the kind when the spec has none: the table fits its column at 390 px and up.
      const tr = el('tr', { 'data-id': j.id },
        el('td', { title: j.id }, el('code', {}, j.id.slice(0, 8))),
        el('td', { class: j.name ? 'name' : 'name muted', title: j.name || '' }, j.name || `(${j.kind || 'job'})`),
        el('td', {}, el('span', { class: `state ${j.state}` }, j.state)),
        el('td', { class: 'num' }, fmtCount(j.samples)));
      if (j.id === selectedId) tr.classList.add('selected');
      tr.addEventListener('click', () => { location.hash = `#/jobs/${encodeURIComponent(j.id)}`; });
      tbody.append(tr);
    }
  }

  // ------------------------------------------------------------------ the form

  async function loadExamples() {
    try {
      const data = await api('GET', '/examples/index.json');
      const sel = $('example-select');
      for (const ex of data.examples || []) {
        const label = `${ex.name}${ex.kind ? ` (${ex.kind}${ex.image ? ', image' : ''})` : ''}`;
        sel.append(el('option', { value: ex.url }, label));
      }
    } catch (e) { /* no examples bundled */ }
  }

  async function pickExample() {
    const url = $('example-select').value;
    if (!url) return;
    const res = await fetch(url);
    $('spec').value = await res.text();
  }

  function showResult(node, isError) {
    const box = $('submit-result');
    box.replaceChildren(node);
    box.className = isError ? 'error-text' : '';
  }

  // The form's spec, parsed: a clear message before the server is asked. Null (and the
  // parser's message shown) when it is not JSON.
  function readSpec() {
    const text = $('spec').value.trim();
    try {
      return { text, spec: JSON.parse(text) };
    } catch (e) {
      showResult(el('pre', {}, `not JSON: ${e.message}`), true);
      return null;
    }
  }

  async function validate() {
    const read = readSpec();
    if (!read) return;
    const { text } = read;
    showResult(el('p', { class: 'muted' }, 'validating (short pilot run)…'));
    try {
      const r = await api('POST', '/v1/jobs/validate', text);
      showResult(validationView(r));
    } catch (e) {
      showResult(el('pre', {}, e.message), true);
    }
  }

  // The validate answer as a person reads it: what stops the job, after how many
  // samples and how long, the cost of tighter targets, then the plan (folded).
  function validationView(r) {
    const p = r.prediction;
    const pilot = r.pilot || {};
    const rows = [];
    if (p) {
      rows.push(['stops by', p.stops_by || '—']);
      rows.push(['samples', fmtCount(p.samples)]);
      rows.push(['compute time', fmtDuration(p.seconds)]);
      if (pilot.job_samples_per_second) rows.push(['at', `${fmtCount(Math.round(pilot.job_samples_per_second))} samples/s`]);
      if (p.reliable === false) rows.push(['reliable', 'no: the variance may be infinite (heavy tail)']);
      for (const c of p.cost_curve || []) {
        if (c.samples === null || c.samples === undefined) continue;  // no relative error (an image, a zero mean)
        rows.push([`rel. error ${c.rel_error}`, `${fmtCount(c.samples)} samples, ${fmtDuration(c.seconds)}`]);
      }
    } else {
      rows.push(['prediction', pilot.error || pilot.note || r.note || 'none (the pilot did not run)']);
    }
    for (const w of pilot.warnings || []) rows.push(['warning', w]);
    const table = el('table', { class: 'kv prediction', id: 'prediction' }, el('tbody', {},
      ...rows.map(([k, v]) => el('tr', {}, el('td', {}, k), el('td', {}, v)))));
    const head = el('p', {}, `valid ${r.kind || (r.plan && r.plan.kind) || ''} job`);
    if (p && p.seconds > 60) {
      head.append(el('strong', { class: 'error-text' }, ` · predicted ${fmtDuration(p.seconds)} of compute`));
    }
    return el('div', {}, head, table, ...suggestionView(r.suggestion),
      el('details', {}, el('summary', {}, 'plan'), el('pre', {}, JSON.stringify(r.plan, null, 2))));
  }

  // The server's faster estimator for an integral that names none (validate's
  // "suggestion", docs/api.md), as the CLI's "faster:" line, with a button that puts it
  // into the spec and validates again.
  function suggestionView(s) {
    if (!s || typeof s !== 'object') return [];
    const w = s.would_choose || {};
    let text = `the auto estimator would choose ${w.estimator || '?'}${w.periodize ? ` (${w.periodize})` : ''}`;
    if (typeof s.fewer_evaluations === 'number') {
      text += `: about ${fmtCount(Math.round(s.fewer_evaluations))}× fewer integrand evaluations ` +
        `(${fmtCount(Math.round(s.predicted_evaluations))} against the default's ` +
        `${fmtCount(Math.round(s.default_predicted_evaluations))})`;
    }
    if (typeof s.predicted_seconds === 'number') text += `, about ${fmtDuration(s.predicted_seconds)} of compute`;
    const use = el('button', { type: 'button', id: 'use-suggestion' }, 'use it');
    use.addEventListener('click', () => {
      const read = readSpec();
      if (!read) return;
      $('spec').value = JSON.stringify({ ...read.spec, estimator: s.estimator }, null, 2);
      validate();
    });
    return [el('p', { id: 'suggestion' }, el('strong', {}, 'faster: '), text, ' ', use)];
  }

  // Submit validates first (as `tally submit` does) and, when the pilot predicts more
  // compute than the "ask above" seconds (60 by default, the CLI's --warn-seconds), asks
  // before submitting. No prediction (too many pilots, the pilot failed) asks nothing.
  let pendingSubmit = null;

  async function submit(ev) {
    ev.preventDefault();
    const read = readSpec();
    if (!read) return;
    const { text } = read;
    askToSubmit(null);
    showResult(el('p', { class: 'muted' }, 'checking the cost (short pilot run)…'));
    let v = null;
    try {
      v = await api('POST', '/v1/jobs/validate', text);
    } catch (e) {
      // The spec's own problem (4xx) is the submit's too: show it. Otherwise (503: too
      // many pilots) submit without a prediction, as the CLI does.
      if (e.status >= 400 && e.status < 500) { showResult(el('pre', {}, e.message), true); return; }
    }
    const limit = Number($('warn-seconds').value);
    const seconds = v && v.prediction ? v.prediction.seconds : null;
    if (typeof seconds === 'number' && Number.isFinite(limit) && limit >= 0 && seconds > limit) {
      showResult(validationView(v));
      askToSubmit(text, `The pilot predicts ${fmtDuration(seconds)} of compute (stops by ${v.prediction.stops_by || '—'}), ` +
        `more than ${fmtDuration(limit)}. Submit it?`);
      return;
    }
    await submitText(text);
  }

  function askToSubmit(text, question) {
    pendingSubmit = text;
    $('confirm-submit').hidden = text === null;
    $('confirm-text').textContent = question || '';
  }

  async function submitText(text) {
    try {
      const r = await api('POST', '/v1/jobs', text);
      showResult(el('p', {}, 'submitted ', el('code', {}, r.id)));
      location.hash = `#/jobs/${encodeURIComponent(r.id)}`;
      refreshJobs();
    } catch (e) {
      showResult(el('pre', {}, e.message), true);
    }
  }

  // ------------------------------------------------------------------ job view

  const requeuedFrom = new Map();  // new job id -> the job it requeued

  // The convergence curve from a status's trace: [compute s, error] with the error the
  // plot shows. Integrals: the standard error. Images: the mean CI half-width, which the
  // trace keeps divided by the critical value (std. error = σ/√n with z σ/√n the
  // half-width, common/lighting/image_kernel.cpp): scaled by the factor that makes the
  // trace's last point the status's `error.abs` (both from the same state).
  function traceCurve(s, image) {
    const pts = (s.trace || []).filter((t) => t[0] > 0 && t[3] > 0);
    if (!image) return pts.map((t) => [t[0], t[3]]);
    const last = pts[pts.length - 1];
    const abs = s.error && s.error.abs;
    if (!last || !(abs > 0) || !Number.isFinite(abs) || last[1] !== s.samples) return [];
    const z = abs / last[3];
    return pts.map((t) => [t[0], t[3] * z]);
  }

  class JobView {
    constructor(id) {
      this.id = id;
      this.status = null;
      this.es = null;
      this.closed = false;
      this.lastEventId = null;
      this.lastPass = 0;
      this.ended = false;
      this.endStatus = false;  // the status read at the end has arrived
      this.progress = null;
      this.points = [];          // convergence: [compute_seconds, error]
      this.tiles = new Map();    // tile -> {x, y, w, h, mean, se, samples, pass}
      this.dirty = new Map();    // tile -> pass of the newest tile event not yet fetched
      this.inflight = 0;
      this.large = false;        // drawn from image.png (setupImage)
      // The large path's one request: dirty (a pass changed the image since the last
      // request began), inflight, when the last began, what it cost (ms), failures.
      this.png = { dirty: false, inflight: false, last: -Infinity, cost: 0, failures: 0, retryAt: 0, draws: 0 };
      this.lastFlush = 0;
      this.firstTileAt = 0;
      this.timer = null;
      this.retryDelay = 1000;
      this.mode = 'mean';
      this.canvas = $('image');
      this.ctx = this.canvas.getContext('2d', { willReadFrequently: true });
      Object.assign(hook, { jobId: id, passesSeen: [], eventIds: [], tileFetches: 0, tileEvents: 0, flushes: 0,
                            tilesEvents: 0, imageFetches: 0, imageDraws: 0, large: false,
                            reconnects: 0, ended: false, settled: false, lastEventId: null, points: this.points });
      setZoom('fit');
    }

    async start() {
      $('job-view').hidden = false;
      $('job-id').textContent = this.id;
      $('job-name').textContent = '';
      for (const id of ['download-exr', 'download-png']) $(id).hidden = true;
      $('plan').textContent = '';
      $('stats').querySelector('tbody').replaceChildren();
      const from = requeuedFrom.get(this.id);
      $('job-origin').hidden = !from;
      if (from) {
        $('job-origin-link').textContent = from;
        $('job-origin-link').href = `#/jobs/${encodeURIComponent(from)}`;
      }
      this.message(null);
      await this.loadStatus();
      if (this.closed) return;
      this.connect(null);
      this.timer = setInterval(() => this.tick(), 50);
    }

    close() {
      this.closed = true;
      if (this.es) this.es.close();
      this.es = null;
      clearInterval(this.timer);
    }

    message(text, info) {
      const m = $('job-message');
      m.hidden = !text;
      m.textContent = text || '';
      m.className = info ? 'message info' : 'message';
    }

    async loadStatus() {
      try {
        this.status = await api('GET', `/v1/jobs/${encodeURIComponent(this.id)}`);
      } catch (e) {
        this.message(e.message);
        return;
      }
      const s = this.status;
      $('job-name').textContent = s.spec && typeof s.spec.name === 'string' ? s.spec.name : '';
      if (typeof s.priority === 'number') $('priority-select').value = String(s.priority);
      this.setState(s.state, s.stop_reason);
      // The effects (what is on, what is off, why) first, then the rest of the plan.
      const plan = s.plan && typeof s.plan === 'object' && 'plan' in s.plan ? { plan: s.plan.plan, ...s.plan } : s.plan;
      $('plan').textContent = JSON.stringify(plan, null, 2);
      const rule = s.stop_rule || {};
      const cur = s.samples || 0;
      $('extend-samples').value = rule.max_samples ? Math.max(rule.max_samples * 2, cur * 2) : Math.max(cur * 2, 1000);
      if (s.error_message) this.message(s.error_message);
      this.setupImage(s);
      // The history before this page opened: the job's trace (at most 512 points, thinned
      // evenly; [compute s, samples, mean, std. error]), kept for every kind.
      if (this.points.length === 0 && Array.isArray(s.trace)) {
        for (const [x, y] of traceCurve(s, !!this.image)) this.points.push([x, y]);
      }
      if (s.passes !== undefined) this.onProgress(s, true);
    }

    setupImage(s) {
      let w = 0, h = 0;
      const img = s.result && s.result.image ? s.result.image : null;
      if (img) { w = img.width; h = img.height; }
      else if (s.spec && s.spec.query && s.spec.query.type === 'image' && s.spec.scene && s.spec.scene.camera) {
        [w, h] = s.spec.scene.camera.resolution;
      }
      if (!w || !h) { $('image-box').hidden = true; this.image = null; return; }
      $('image-box').hidden = false;
      const base = `/v1/jobs/${encodeURIComponent(this.id)}/image`;
      for (const [id, ext] of [['download-exr', 'exr'], ['download-png', 'png']]) {
        $(id).href = `${base}.${ext}`;
        $(id).setAttribute('download', `${this.id}.${ext}`);
        $(id).hidden = false;
      }
      if (!this.image || this.image.w !== w || this.image.h !== h) {
        const tileSize = img ? img.tile_size : (s.spec.query.tile_size || 32);
        const cols = Math.ceil(w / tileSize);
        const tileCount = img ? img.tiles : cols * Math.ceil(h / tileSize);
        this.image = { w, h, tileSize, tileCount, cols };
        this.large = tileCount > LARGE_TILES || w * h > LARGE_PIXELS;
        hook.large = this.large;
        this.canvas.width = w;
        this.canvas.height = h;
        this.ctx.fillStyle = '#000';
        this.ctx.fillRect(0, 0, w, h);
        this.setupLarge();
        layoutImage();
      }
      // Draw whatever the job already has: every tile once (the whole PNG once, for a
      // large image), unless events have announced changes already. Also at the end: a
      // job that ended before the event stream connected sends a snapshot without tile
      // events.
      if (this.large) {
        if ((s.passes || 0) > 0 && this.png.draws === 0 && !this.png.inflight) this.png.dirty = true;
        return;
      }
      const count = this.image.tileCount;
      if ((s.passes || 0) > 0 && this.tiles.size === 0 && this.dirty.size === 0 && this.inflight === 0) {
        for (let t = 0; t < count; ++t) this.dirty.set(t, s.passes);
      }
    }

    // A large image has no standard-error map (it needs every tile's JSON): the control is
    // off and a note says why and where the errors are.
    setupLarge() {
      const { w, h, tileCount } = this.image;
      $('view-stderr').disabled = this.large;
      $('view-stderr').parentElement.title = this.large
        ? 'needs per-tile data: only for images up to 1,024 tiles and 1,048,576 pixels' : '';
      if (this.large && this.mode !== 'mean') this.setMode('mean');
      if (this.large) document.querySelector('input[name=view][value=mean]').checked = true;
      $('large-note').hidden = !this.large;
      $('large-note').textContent = this.large
        ? `A large image (${w}×${h}, ${tileCount.toLocaleString('en')} tiles): drawn from image.png, refreshed every 2 s or ` +
          'more. The standard-error map is not shown above 1,024 tiles or 1,048,576 pixels; the EXR download has ' +
          'the per-pixel standard errors (StdErr.R/G/B).'
        : '';
      $('tile-info').textContent = '';
    }

    hasErrorTarget() {
      const r = (this.status && this.status.stop_rule) || {};
      return r.abs_error > 0 || r.rel_error > 0;
    }

    setState(state, reason) {
      const e = $('job-state');
      e.textContent = state + (reason && reason !== 'none' && reason !== 'running' ? ` · ${reason}` : '');
      e.className = `state ${state}`;
      const active = state === 'queued' || state === 'running';
      $('cancel-btn').disabled = !active;
      $('extend-btn').disabled = active;
      $('delete-btn').disabled = active;
      // A finished job keeps the priority it ran with; a failed or cancelled one may run again.
      $('priority-select').disabled = !active;
      $('priority-btn').disabled = !active;
      $('requeue-btn').hidden = state !== 'failed' && state !== 'cancelled';
    }

    // --- the event stream -------------------------------------------------

    connect(afterId) {
      if (this.closed) return;
      let url = `/v1/jobs/${encodeURIComponent(this.id)}/events`;
      // A new EventSource sends no Last-Event-ID; the query parameter does the same.
      if (afterId !== null && afterId !== undefined) url += `?last_event_id=${encodeURIComponent(afterId)}`;
      const es = new EventSource(url);
      hook.streamsOpened++;
      this.es = es;
      const on = (type, fn) => es.addEventListener(type, (ev) => {
        if (this.es !== es) return;
        if (ev.lastEventId) { this.lastEventId = ev.lastEventId; hook.lastEventId = ev.lastEventId; }
        if (this.reconnecting) { this.reconnecting = false; this.message(null); }
        hook.eventIds.push(ev.lastEventId);
        let data = null;
        try { data = JSON.parse(ev.data); } catch (e) { return; }
        fn(data);
      });
      on('progress', (d) => this.onProgress(d, false));
      on('state', (d) => { this.setState(d.state, d.stop_reason); if (d.error_message) this.message(d.error_message); });
      on('tile', (d) => this.onTile(d));
      on('tiles', (d) => this.onTiles(d));
      on('end', (d) => this.onEnd(d));
      on('shutdown', () => this.message('the server is shutting down; the page reconnects when it is back', true));
      es.onopen = () => { this.retryDelay = 1000; if (!this.ended) this.message(null); };
      es.onerror = () => {
        if (this.es !== es || this.ended) return;
        if (es.readyState === EventSource.CLOSED) {
          // The browser gave up (e.g. an HTTP error while the server restarts, or a 401
          // after the session ended): reconnect ourselves from the last id we saw, with
          // backoff, unless the session is gone.
          hook.reconnects++;
          hook.streamClosed++;
          fetch('/v1/session').then((r) => {
            if (r.status === 401) showLogin('the session has ended; log in again');
          }).catch(() => {});
          this.es = null;
          const delay = this.retryDelay;
          this.retryDelay = Math.min(this.retryDelay * 2, 15000);
          setTimeout(() => { if (!this.closed && !this.ended) this.connect(this.lastEventId); }, delay);
        } else {
          // CONNECTING: the browser retries by itself and sends Last-Event-ID.
          hook.reconnects++;
          this.reconnecting = true;
          this.message('connection lost; reconnecting…', true);
        }
      };
    }

    // Simulates a dropped connection (tests): close, then resume from the last id.
    dropStream() {
      if (this.es) this.es.close();
      this.es = null;
      hook.reconnects++;
      setTimeout(() => this.connect(this.lastEventId), 300);
    }

    onProgress(p, fromStatus) {
      if (!fromStatus) {
        hook.passesSeen.push(p.pass ?? p.passes);
        this.lastPass = p.pass ?? p.passes;
      }
      this.progress = p;
      const x = p.compute_seconds;
      const y = this.image ? (p.error && p.error.abs) : (p.estimate && p.estimate.std_error);
      if (x > 0 && y > 0 && Number.isFinite(y)) {
        // Keep about 500 points per decade of time: a long job's plot stays cheap.
        const pts = this.points, last = pts[pts.length - 1], prev = pts[pts.length - 2];
        if (!last || x > last[0]) {
          if (prev && Math.log10(x) - Math.log10(prev[0]) < 0.002) pts[pts.length - 1] = [x, y];
          else pts.push([x, y]);
        }
      }
      // Statistics and plot are drawn at most every 200 ms (tick), not per event:
      // a resumed stream may replay thousands of passes at once.
      this.renderDue = true;
      if (fromStatus) this.render();
    }

    render() {
      this.renderDue = false;
      this.lastRender = performance.now();
      this.renderStats();
      this.renderPlot();
    }

    onTile(d) {
      hook.tileEvents++;
      if (!this.image) return;
      if (!this.firstTileAt) this.firstTileAt = performance.now();
      if (this.large) { this.png.dirty = true; return; }
      this.dirty.set(d.tile, d.pass);
      if (!this.tiles.has(d.tile)) this.tiles.set(d.tile, { x: d.x, y: d.y, w: d.w, h: d.h, pass: 0 });
    }

    // A pass that refined more than 64 tiles sends one `tiles` event: {count, first, last,
    // x, y, w, h, pass}, every refined tile's index in [first, last] and its pixels inside
    // the rectangle. Every tile in that range that meets the rectangle is marked (row-major
    // tiles: a superset of the refined ones at worst).
    onTiles(d) {
      hook.tilesEvents++;
      if (!this.image) return;
      if (!this.firstTileAt) this.firstTileAt = performance.now();
      if (this.large) { this.png.dirty = true; return; }
      const { w, h, tileSize: ts, tileCount, cols } = this.image;
      const x0 = d.x, y0 = d.y, x1 = d.x + d.w, y1 = d.y + d.h;
      const last = Math.min(tileCount - 1, d.last);
      for (let t = Math.max(0, d.first); t <= last; ++t) {
        const x = (t % cols) * ts, y = Math.floor(t / cols) * ts;
        const tw = Math.min(ts, w - x), th = Math.min(ts, h - y);
        if (x >= x1 || y >= y1 || x + tw <= x0 || y + th <= y0) continue;
        this.dirty.set(t, d.pass);
        if (!this.tiles.has(t)) this.tiles.set(t, { x, y, w: tw, h: th, pass: 0 });
      }
    }

    onEnd(d) {
      this.ended = true;
      hook.ended = true;
      if (this.es) this.es.close();
      this.es = null;
      this.setState(d.state, d.stop_reason);
      if (d.error_message) this.message(d.error_message);
      else if (d.target_met === false && d.state === 'succeeded' && this.hasErrorTarget()) {
        this.message(`stopped (${d.stop_reason}) before the error target was met`, true);
      }
      this.lastFlush = 0;  // draw the final tiles now
      if (this.large) this.png.dirty = true;  // and the final image, once the request in flight is back
      this.render();
      // Not settled before the final status is in (it may announce every tile).
      this.endStatus = false;
      this.loadStatus().finally(() => { this.endStatus = true; this.tick(); });
      refreshJobs();
    }

    // The tile fetch period grows as the image converges: 250 ms for the first
    // seconds, then ∝ √time (the visible change per update shrinks like 1/√n), at most 2 s.
    interval() {
      if (!this.firstTileAt) return 250;
      const t = (performance.now() - this.firstTileAt) / 1000;
      return Math.min(2000, Math.max(250, 250 * Math.sqrt(t / 4)));
    }

    tick() {
      if (this.closed) return;
      const now = performance.now();
      if (this.renderDue && (this.ended || now - (this.lastRender || 0) >= 200)) this.render();
      if (!this.image) return;
      if (this.large) {
        const png = this.png;
        if (png.dirty && !png.inflight && now >= png.retryAt &&
            now - png.last >= (this.ended ? 0 : this.imageInterval())) {
          this.fetchImage();
        }
        hook.settled = this.ended && this.endStatus && !png.dirty && !png.inflight;
        return;
      }
      if (this.dirty.size > 0 && this.inflight === 0 && now - this.lastFlush >= (this.ended ? 0 : this.interval())) {
        this.flush();
      }
      hook.settled = this.ended && this.endStatus && this.dirty.size === 0 && this.inflight === 0;
    }

    // A large image's refresh period: 2 s for the first 16 s of tiles, then ∝ √time as
    // for tiles, at most 10 s; and never less than 4× what the last request cost (its
    // encode on the server, the transfer and the decode), so the page spends at most a
    // fifth of its time on a frame that a slow link or a busy server makes expensive.
    imageInterval() {
      const t = this.firstTileAt ? (performance.now() - this.firstTileAt) / 1000 : 0;
      return Math.max(4 * this.png.cost, Math.min(10000, Math.max(2000, 2000 * Math.sqrt(t / 16))));
    }

    // One request for the whole image; decoded by createImageBitmap (off the main thread,
    // without colour conversion: the canvas gets the PNG's 8-bit sRGB values as they are)
    // and drawn in one drawImage. Never two at once, so answers cannot overtake each other.
    async fetchImage() {
      const png = this.png;
      png.dirty = false;
      png.inflight = true;
      const t0 = performance.now();
      png.last = t0;
      hook.imageFetches++;
      let bitmap = null;
      try {
        const r = await fetch(`/v1/jobs/${encodeURIComponent(this.id)}/image.png`, { cache: 'no-store' });
        if (!r.ok) {
          const err = new Error(`image.png: ${r.status} ${await r.text().catch(() => '')}`.trim());
          err.status = r.status;
          throw err;
        }
        const blob = await r.blob();
        bitmap = await createImageBitmap(blob, { colorSpaceConversion: 'none', premultiplyAlpha: 'none' });
        if (this.closed) return;
        if (bitmap.width !== this.image.w || bitmap.height !== this.image.h) {
          throw new Error(`image.png is ${bitmap.width}×${bitmap.height}, the job's image ${this.image.w}×${this.image.h}`);
        }
        this.ctx.drawImage(bitmap, 0, 0);
        png.draws++;
        hook.imageDraws++;
        png.cost = performance.now() - t0;
        png.failures = 0;
        $('tile-info').textContent = `image.png ${fmtNum(blob.size / 1e6, 3)} MB in ${Math.round(png.cost)} ms` +
          (this.ended ? '' : ` · every ${fmtNum(this.imageInterval() / 1000, 2)} s`);
      } catch (e) {
        if (this.closed) return;
        // Try again later (1 s, 2 s, … 30 s), also after the end; a server that cannot
        // encode PNG (501) or has lost the job (404) is not asked again.
        png.failures++;
        png.retryAt = performance.now() + Math.min(30000, 1000 * 2 ** (png.failures - 1));
        if (e.status !== 501 && e.status !== 404) png.dirty = true;
        $('tile-info').textContent = `image.png failed: ${e.message}`;
      } finally {
        if (bitmap) bitmap.close();
        png.inflight = false;
        this.tick();
      }
    }

    flush() {
      this.lastFlush = performance.now();
      hook.flushes++;
      const batch = [...this.dirty.entries()];
      this.dirty.clear();
      const base = `/v1/jobs/${encodeURIComponent(this.id)}/tiles/`;
      for (const [n, pass] of batch) {
        this.inflight++;
        hook.tileFetches++;
        fetch(base + n).then((r) => (r.ok ? r.json() : Promise.reject(new Error(`tile ${n}: ${r.status}`))))
          .then((t) => this.onTileData(n, t))
          .catch(() => { if (!this.dirty.has(n)) this.dirty.set(n, pass); })
          .finally(() => { this.inflight--; this.tick(); });
      }
      $('tile-info').textContent = `${batch.length} tile${batch.length === 1 ? '' : 's'} updated · every ${Math.round(this.interval())} ms`;
    }

    onTileData(n, t) {
      if (this.closed) return;
      const tile = {
        x: t.x, y: t.y, w: t.w, h: t.h, pass: t.pass,
        mean: Float32Array.from(t.mean), se: Float32Array.from(t.std_error), samples: Float32Array.from(t.samples),
      };
      const old = this.tiles.get(n);
      if (old && old.mean && old.pass > tile.pass) return;  // an older answer overtaken
      this.tiles.set(n, tile);
      this.drawTile(tile);
    }

    drawTile(t) {
      const img = this.ctx.createImageData(t.w, t.h);
      const px = img.data;
      for (let i = 0, m = t.w * t.h; i < m; ++i) {
        let r, g, b;
        if (this.mode === 'mean') {
          r = srgb8(t.mean[3 * i]); g = srgb8(t.mean[3 * i + 1]); b = srgb8(t.mean[3 * i + 2]);
        } else {
          const mu = Math.abs(t.mean[3 * i]) + Math.abs(t.mean[3 * i + 1]) + Math.abs(t.mean[3 * i + 2]);
          const se = t.se[3 * i] + t.se[3 * i + 1] + t.se[3 * i + 2];
          let v = 0;
          if (se > 0) v = (Math.log10(Math.max(se / Math.max(mu, 1e-12), 1e-3)) + 3) / 3;  // 0.1% .. 100%
          [r, g, b] = heat(v);
        }
        px[4 * i] = r; px[4 * i + 1] = g; px[4 * i + 2] = b; px[4 * i + 3] = 255;
      }
      this.ctx.putImageData(img, t.x, t.y);
    }

    setMode(mode) {
      if (this.large && mode !== 'mean') return;  // no tile data: no heat map (setupLarge)
      this.mode = mode;
      $('heat-legend').hidden = mode !== 'stderr';
      for (const t of this.tiles.values()) if (t.mean) this.drawTile(t);
    }

    // --- statistics and the plot ---------------------------------------

    renderStats() {
      const p = this.progress;
      if (!p) return;
      const rows = [];
      const est = p.estimate || {};
      const conf = est.confidence ? `${Math.round(est.confidence * 1000) / 10}%` : '95%';
      rows.push(['pass', p.pass ?? p.passes]);
      // An image job counts samples per pixel.
      rows.push([this.image ? 'spp (samples per pixel)' : 'samples', fmtCount(p.samples)]);
      if (this.image) {
        rows.push([`mean ${conf} CI half-width`, `${fmtNum(p.error && p.error.abs)} (relative ${fmtNum(p.error && p.error.rel && 100 * p.error.rel, 3)}%)`]);
      } else {
        rows.push(['mean ± std. error', `${fmtNum(est.mean, 7)} ± ${fmtNum(est.std_error, 3)}`]);
        rows.push([`${conf} CI`, `[${fmtNum(est.ci && est.ci[0], 7)}, ${fmtNum(est.ci && est.ci[1], 7)}]`]);
        rows.push(['relative error', p.error ? `${fmtNum(p.error.rel && 100 * p.error.rel, 3)}%` : '—']);
      }
      rows.push([this.image ? 'spp/s' : 'samples/s', fmtCount(Math.round(p.samples_per_second || 0))]);
      rows.push(['compute time', fmtDuration(p.compute_seconds)]);
      const eta = p.eta_seconds ?? (p.prediction && p.prediction.seconds_remaining);
      rows.push(['ETA', this.ended ? 'done' : fmtDuration(eta)]);
      if (p.stop_reason && p.stop_reason !== 'none') rows.push(['stop reason', `${p.stop_reason}${p.target_met ? ' (target met)' : ''}`]);
      const tbody = $('stats').querySelector('tbody');
      tbody.replaceChildren(...rows.map(([k, v]) => el('tr', {}, el('td', {}, k), el('td', {}, v))));
      // Progress: compute time spent over time spent + time still needed.
      let frac = this.ended ? 1 : 0;
      if (!this.ended && eta !== null && eta !== undefined && Number.isFinite(eta) && p.compute_seconds > 0) {
        const wall = p.samples_per_second > 0 ? p.samples / p.samples_per_second : p.compute_seconds;
        frac = wall / (wall + eta);
      }
      $('progress-bar').style.width = `${Math.round(100 * Math.min(1, Math.max(0, frac)))}%`;
    }

    // Log-log plot of the error against compute time, with a t^-1/2 guide.
    renderPlot() {
      const c = $('plot');
      const ctx = c.getContext('2d');
      const W = c.width, H = c.height, L = 58, R = 12, T = 12, B = 36;
      ctx.clearRect(0, 0, W, H);
      ctx.font = '11px system-ui, sans-serif';
      ctx.fillStyle = '#6b7482';
      const pts = this.points;
      if (pts.length < 2) {
        if (this.ended) {
          // One pass (or none with an error bar): no curve to draw.
          const e = this.progress && this.progress.error;
          ctx.fillText('fewer than two passes with an error bar;', L, H / 2 - 8);
          ctx.fillText(`final: CI half-width ${fmtNum(e && e.abs)}`, L, H / 2 + 8);
          return;
        }
        ctx.fillText('the history starts when the page opens:', L, H / 2 - 8);
        ctx.fillText('fewer than two passes seen so far', L, H / 2 + 8);
        return;
      }
      const lx = pts.map((p) => Math.log10(p[0])), ly = pts.map((p) => Math.log10(p[1]));
      let x0 = Math.floor(Math.min(...lx)), x1 = Math.ceil(Math.max(...lx));
      let y0 = Math.floor(Math.min(...ly)), y1 = Math.ceil(Math.max(...ly));
      if (x1 === x0) x1++;
      if (y1 === y0) y1++;
      const sx = (v) => L + ((v - x0) / (x1 - x0)) * (W - L - R);
      const sy = (v) => H - B - ((v - y0) / (y1 - y0)) * (H - T - B);
      ctx.strokeStyle = '#e3e6ea';
      ctx.lineWidth = 1;
      ctx.textAlign = 'center';
      for (let d = x0; d <= x1; ++d) {
        ctx.beginPath(); ctx.moveTo(sx(d), T); ctx.lineTo(sx(d), H - B); ctx.stroke();
        ctx.fillText(`1e${d}`, sx(d), H - B + 14);
      }
      ctx.textAlign = 'right';
      for (let d = y0; d <= y1; ++d) {
        ctx.beginPath(); ctx.moveTo(L, sy(d)); ctx.lineTo(W - R, sy(d)); ctx.stroke();
        ctx.fillText(`1e${d}`, L - 4, sy(d) + 4);
      }
      ctx.textAlign = 'center';
      ctx.fillText('compute time (s)', L + (W - L - R) / 2, H - 6);
      ctx.save();
      ctx.translate(12, T + (H - T - B) / 2);
      ctx.rotate(-Math.PI / 2);
      ctx.fillText(this.image ? 'mean CI half-width' : 'standard error', 0, 0);
      ctx.restore();
      // Guide: slope -1/2 through the first point.
      ctx.strokeStyle = '#b8c0cc';
      ctx.setLineDash([4, 4]);
      ctx.beginPath();
      ctx.moveTo(sx(lx[0]), sy(ly[0]));
      ctx.lineTo(sx(x1), sy(ly[0] - 0.5 * (x1 - lx[0])));
      ctx.stroke();
      ctx.setLineDash([]);
      ctx.strokeStyle = '#2f6fdb';
      ctx.lineWidth = 2;
      ctx.beginPath();
      for (let i = 0; i < pts.length; ++i) (i ? ctx.lineTo : ctx.moveTo).call(ctx, sx(lx[i]), sy(ly[i]));
      ctx.stroke();
      ctx.fillStyle = '#2f6fdb';
      ctx.beginPath();
      ctx.arc(sx(lx[lx.length - 1]), sy(ly[ly.length - 1]), 3, 0, 2 * Math.PI);
      ctx.fill();
      ctx.fillStyle = '#6b7482';
      ctx.textAlign = 'right';
      ctx.fillText('– – ∝ t^(−1/2)', W - R - 4, T + 12);
    }

    // --- buttons --------------------------------------------------------

    async remove() {
      try {
        await api('DELETE', `/v1/jobs/${encodeURIComponent(this.id)}`);
        location.hash = '';
        refreshJobs();
      } catch (e) { this.message(e.message); }
    }

    async cancel() {
      try { await api('DELETE', `/v1/jobs/${encodeURIComponent(this.id)}`); refreshJobs(); }
      catch (e) { this.message(e.message); }
    }

    async setPriority() {
      const p = Number($('priority-select').value);
      try {
        const r = await api('PATCH', `/v1/jobs/${encodeURIComponent(this.id)}`, { priority: p });
        $('priority-select').value = String(r.priority);
        this.message(`priority ${r.priority}`, true);
        refreshJobs();
      } catch (e) { this.message(e.message); }
    }

    // Runs a failed or cancelled job again: its spec as submitted (with its name and
    // seed), at its priority, as a new job of the caller (POST /v1/jobs, admitted like
    // any submit: quotas, the queue, the memory budget); the page opens the new job.
    async requeue() {
      const s = this.status;
      if (!s || !s.spec) { this.message('the job\'s spec is not known yet'); return; }
      const from = this.id;
      try {
        const r = await api('POST', `/v1/jobs?priority=${encodeURIComponent(s.priority || 0)}`, s.spec);
        requeuedFrom.set(r.id, from);
        location.hash = `#/jobs/${encodeURIComponent(r.id)}`;
        refreshJobs();
      } catch (e) { this.message(e.message); }
    }

    async extend() {
      const n = Number($('extend-samples').value);
      if (!(n > 0)) { this.message('max samples must be a positive number'); return; }
      try {
        await api('POST', `/v1/jobs/${encodeURIComponent(this.id)}/extend`, { max_samples: Math.round(n) });
        this.message(null);
        this.ended = false;
        hook.ended = false;
        hook.settled = false;
        this.connect(this.lastEventId);
        refreshJobs();
      } catch (e) { this.message(e.message); }
    }
  }

  // ------------------------------------------------------------------ image scale

  // The canvas holds the image at its own resolution; only its CSS size changes.
  // Fit: the whole image within the panel's width and 70% of the window's height
  // (magnified or reduced). 1:1: one image pixel per device pixel (CSS size = pixels /
  // devicePixelRatio), in a view that scrolls (scrollbars, wheel, touch) and pans with a
  // mouse drag. Pixelated at or above 1:1, filtered below.
  let zoom = 'fit';

  function layoutImage() {
    const canvas = $('image'), box = $('image-view');
    const w = canvas.width, h = canvas.height;
    const dpr = window.devicePixelRatio || 1;
    let cw, ch;
    if (zoom === '1:1') {
      cw = w / dpr; ch = h / dpr;
    } else {
      const availW = $('image-box').clientWidth, availH = Math.max(120, 0.7 * window.innerHeight);
      const s = Math.min(availW / w, availH / h);
      cw = Math.max(1, Math.floor(w * s)); ch = Math.max(1, Math.floor(h * s));
    }
    canvas.style.width = `${cw}px`;
    canvas.style.height = `${ch}px`;
    canvas.classList.toggle('smooth', cw * dpr < w - 0.5);
    box.classList.toggle('one', zoom === '1:1');
  }

  // Sets the scale; at 1:1 the point at fractions (fx, fy) of the image goes to the
  // middle of the view (the image's centre by default).
  function setZoom(z, fx = 0.5, fy = 0.5) {
    zoom = z;
    hook.zoom = z;
    $('zoom-fit').setAttribute('aria-pressed', String(z === 'fit'));
    $('zoom-one').setAttribute('aria-pressed', String(z === '1:1'));
    layoutImage();
    const box = $('image-view'), canvas = $('image');
    if (z === '1:1') {
      box.scrollLeft = fx * canvas.clientWidth - box.clientWidth / 2;
      box.scrollTop = fy * canvas.clientHeight - box.clientHeight / 2;
    } else {
      box.scrollLeft = 0;
      box.scrollTop = 0;
    }
  }

  {
    const box = $('image-view'), canvas = $('image');
    $('zoom-fit').addEventListener('click', () => setZoom('fit'));
    $('zoom-one').addEventListener('click', () => setZoom('1:1'));
    // Double click: 1:1 at the pixel clicked, or back to Fit.
    canvas.addEventListener('dblclick', (e) => {
      if (zoom === '1:1') { setZoom('fit'); return; }
      const r = canvas.getBoundingClientRect();
      setZoom('1:1', (e.clientX - r.left) / r.width, (e.clientY - r.top) / r.height);
    });
    // A mouse drag pans at 1:1 (touch scrolls natively; the scrollbars are the box's own).
    let drag = null;
    canvas.addEventListener('pointerdown', (e) => {
      if (zoom !== '1:1' || e.pointerType !== 'mouse' || e.button !== 0) return;
      drag = { x: e.clientX, y: e.clientY, left: box.scrollLeft, top: box.scrollTop };
      canvas.setPointerCapture(e.pointerId);
      box.classList.add('dragging');
      e.preventDefault();
    });
    canvas.addEventListener('pointermove', (e) => {
      if (!drag) return;
      box.scrollLeft = drag.left - (e.clientX - drag.x);
      box.scrollTop = drag.top - (e.clientY - drag.y);
    });
    const end = () => { drag = null; box.classList.remove('dragging'); };
    canvas.addEventListener('pointerup', end);
    canvas.addEventListener('pointercancel', end);
    // The panel's width, the window's height and the device pixel ratio (browser zoom)
    // change the CSS size.
    new ResizeObserver(() => layoutImage()).observe($('image-box'));
    window.addEventListener('resize', () => layoutImage());
  }

  // ------------------------------------------------------------------ routing

  function route() {
    const m = /^#\/jobs\/(.+)$/.exec(location.hash);
    const id = m ? decodeURIComponent(m[1]) : null;
    if (view && view.id === id) return;
    if (view) view.close();
    view = null;
    selectedId = id;
    for (const tr of document.querySelectorAll('#jobs tbody tr')) tr.classList.toggle('selected', tr.dataset.id === id);
    if (!id) { $('job-view').hidden = true; return; }
    view = new JobView(id);
    view.start();
  }

  // ------------------------------------------------------------------ session

  let loggedIn = false;
  let started = false;

  function showLogin(why) {
    loggedIn = false;
    $('server-status').textContent = '';  // not "connecting…": the server answered, it wants a token
    if (view) view.close();
    view = null;
    $('app-main').hidden = true;
    $('who').hidden = true;
    $('login-panel').hidden = false;
    const r = $('login-result');
    r.hidden = !why;
    r.textContent = why || '';
    hook.loggedIn = false;
  }

  window.tally.onUnauthorized = (why) => showLogin(why);

  function showApp(me) {
    loggedIn = true;
    hook.loggedIn = true;
    $('login-panel').hidden = true;
    $('app-main').hidden = false;
    $('who').hidden = !me.access_control;
    $('who-name').textContent = `${me.name} (${me.role})`;
    if (!started) {
      started = true;
      loadExamples();
      setInterval(() => { refreshJobs(); window.tally.workers.refresh(); }, 2000);
    }
    refreshJobs();
    window.tally.workers.refresh();
    selectedId = null;
    route();
  }

  async function checkSession() {
    try {
      showApp(await api('GET', '/v1/session'));
    } catch (e) {
      if (e.status === 401) showLogin(null);
      else { $('server-status').textContent = 'server unreachable'; setTimeout(checkSession, 2000); }
    }
  }

  $('login-form').addEventListener('submit', async (ev) => {
    ev.preventDefault();
    const token = $('login-token').value.trim();
    try {
      const me = await api('POST', '/v1/session', { token });
      $('login-token').value = '';  // the page keeps only the cookie, which it cannot read
      showApp(me);
    } catch (e) {
      showLogin(e.message);
    }
  });
  $('logout-btn').addEventListener('click', async () => {
    try { await api('DELETE', '/v1/session'); } catch (e) { /* the session is gone either way */ }
    showLogin('logged out');
  });

  $('example-select').addEventListener('change', pickExample);
  $('validate-btn').addEventListener('click', validate);
  $('submit-form').addEventListener('submit', submit);
  $('cancel-btn').addEventListener('click', () => view && view.cancel());
  $('delete-btn').addEventListener('click', () => view && view.remove());
  $('extend-btn').addEventListener('click', () => view && view.extend());
  $('priority-btn').addEventListener('click', () => view && view.setPriority());
  $('requeue-btn').addEventListener('click', () => view && view.requeue());
  $('confirm-yes').addEventListener('click', () => { const t = pendingSubmit; askToSubmit(null); if (t !== null) submitText(t); });
  $('confirm-no').addEventListener('click', () => { askToSubmit(null); showResult(el('p', { class: 'muted' }, 'not submitted')); });
  for (const r of document.querySelectorAll('input[name=view]')) {
    r.addEventListener('change', () => view && view.setMode(r.value));
  }
  window.addEventListener('hashchange', () => { if (loggedIn) route(); });
  checkSession();
})();
