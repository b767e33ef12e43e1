// tally preview: the helpers every part of the page shares (docs/preview.md): the JSON
// API call with problem+json errors, number and duration formats, element building.
// Plain script, loaded before workers.js and app.js; everything lives on window.tally.
'use strict';

window.tally = (() => {
  const tally = {};
  tally.$ = (id) => document.getElementById(id);
  // Set by app.js: what a 401 outside the session routes does (show the login).
  tally.onUnauthorized = () => {};

  async function api(method, url, body) {
    const init = { method, headers: { Accept: 'application/json' } };
    if (body !== undefined) {
      init.headers['Content-Type'] = 'application/json';
      init.body = typeof body === 'string' ? body : JSON.stringify(body);
    }
    const res = await fetch(url, init);
    if (res.status === 401 && !url.startsWith('/v1/session')) tally.onUnauthorized('the session has ended; log in again');
    const text = await res.text();
    let json = null;
    try { json = text ? JSON.parse(text) : null; } catch (e) { json = null; }
    if (!res.ok) {
      const err = new Error(problemText(res.status, json, text));
      err.status = res.status;
      err.problem = json;
      throw err;
    }
    return json;
  }

  function problemText(status, p, text) {
    if (p && (p.detail || p.title)) {
      let s = `${status} ${p.title || ''}: ${p.detail || ''}`;
      if (p.pointer) s += `\nat ${p.pointer}`;
      if (Array.isArray(p.errors)) {
        for (const e of p.errors) s += `\n${e.pointer || ''}: ${e.detail || ''}`;
      }
      return s;
    }
    return `${status}: ${text || 'request failed'}`;
  }

  function fmtNum(v, digits = 4) {
    if (v === null || v === undefined || Number.isNaN(v)) return '—';
    if (!Number.isFinite(v)) return v > 0 ? '∞' : '−∞';
    if (v === 0) return '0';
    const a = Math.abs(v);
    if (a >= 1e-3 && a < 1e6) return Number(v.toPrecision(digits)).toString();
    return v.toExponential(digits - 1);
  }

  function fmtCount(n) {
    if (n === null || n === undefined) return '—';
    if (n < 1e3) return String(n);
    const units = [['G', 1e9], ['M', 1e6], ['k', 1e3]];
    for (const [u, s] of units) if (n >= s) return (n / s).toPrecision(3) + u;
    return String(n);
  }

  function fmtDuration(s) {
    if (s === null || s === undefined || !Number.isFinite(s)) return '—';
    if (s < 1) return `${Math.round(s * 1000)} ms`;
    if (s < 60) return `${s.toFixed(1)} s`;
    if (s < 3600) return `${Math.floor(s / 60)} min ${Math.round(s % 60)} s`;
    return `${Math.floor(s / 3600)} h ${Math.round((s % 3600) / 60)} min`;
  }

  function el(tag, attrs, ...children) {
    const e = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs || {})) {
      if (k === 'class') e.className = v; else e.setAttribute(k, v);
    }
    for (const c of children) e.append(c instanceof Node ? c : document.createTextNode(String(c)));
    return e;
  }

  Object.assign(tally, { api, problemText, fmtNum, fmtCount, fmtDuration, el });
  return tally;
})();
