// tally preview: the workers panel (docs/preview.md). In cluster mode (`--redis`)
// GET /v1/workers lists the live tally-worker processes; the panel shows each one's
// name, host, threads, last heartbeat, blocks done and current job, polled with the
// job list. In process (`"executor": "in_process"`), or for a caller the route refuses
// (403: only admins and the metrics role see every tenant's workers), it stays hidden.
'use strict';

window.tally.workers = (() => {
  const { $, api, el, fmtCount } = window.tally;
  let shown = false;

  function ago(seconds) {
    if (typeof seconds !== 'number' || !Number.isFinite(seconds)) return '—';
    return seconds < 1 ? 'just now' : `${seconds < 10 ? seconds.toFixed(1) : Math.round(seconds)} s ago`;
  }

  function render(data) {
    const rows = (data.workers || []).map((w) => el('tr', { 'data-name': w.name },
      el('td', { class: 'name', title: w.name }, w.name),
      el('td', { class: 'host', title: w.host || '' }, w.host || '—'),
      el('td', { class: 'num' }, w.threads ?? '—'),
      el('td', { title: w.last_heartbeat || '' }, ago(w.seconds_since_heartbeat)),
      el('td', { class: 'num' }, fmtCount(w.blocks_done)),
      el('td', {}, w.current_job
        ? el('a', { href: `#/jobs/${encodeURIComponent(w.current_job)}`, title: w.current_job },
          el('code', {}, w.current_job.slice(0, 8)))
        : el('span', { class: 'muted' }, 'idle'))));
    $('workers').querySelector('tbody').replaceChildren(...rows);
    $('workers-empty').hidden = rows.length > 0;
    const threads = (data.workers || []).reduce((n, w) => n + (w.threads || 0), 0);
    $('workers-summary').textContent =
      `${rows.length} worker${rows.length === 1 ? '' : 's'}, ${threads} thread${threads === 1 ? '' : 's'}` +
      (data.redis ? ` · ${data.redis}` : '');
  }

  // Shows the panel when the server runs a cluster executor; hides it otherwise.
  async function refresh() {
    let data = null;
    try {
      data = await api('GET', '/v1/workers');
    } catch (e) {
      data = null;  // 403 for a user or reader, or the server is away: no panel
    }
    shown = !!(data && data.executor && data.executor !== 'in_process');
    $('workers-panel').hidden = !shown;
    if (shown) render(data);
  }

  return { refresh, shown: () => shown };
})();
