// The preview page in a real browser (Debian chromium, headless, via playwright-core)
// against a real tally-server: the form submits a lighting image job from examples/,
// the canvas is filled tile by tile from the event stream and must equal the
// server's PNG of the finished job (±1 per channel); a cut connection and a dropped
// EventSource must resume with every pass seen exactly once. A large image (over 1,024
// tiles) is drawn from image.png instead of per-tile JSON, with Fit / 1:1 / pan, and the
// page stays responsive while it runs.
//
// Env: TALLY_SERVER (path to tally-server, required), CHROMIUM (default
// /usr/bin/chromium), PREVIEW_SCREENSHOT_DIR (write docs/img/preview-*.png there).
import assert from 'node:assert/strict';
import fs from 'node:fs';
import path from 'node:path';
import { after, before, describe, test } from 'node:test';
import { chromium } from 'playwright-core';

import { decodePng, launchBrowser, sleep, startProxy, startServer, waitFor } from './support.mjs';

const serverBinary = process.env.TALLY_SERVER;
const shotDir = process.env.PREVIEW_SCREENSHOT_DIR || '';
const EXAMPLE = '/examples/preview_image.json';
// The large-image test's job: 2048×1152 (2,304 tiles of 32 px, over the page's 1,024),
// 4 passes of 1 sample per pixel: about 10 s on 2 cores. A 4K frame (8,160 tiles) takes
// about 30 s here, mostly the server's PNG encodes: PREVIEW_LARGE_SIZE=3840x2160 runs it.
const LARGE_SIZE = (process.env.PREVIEW_LARGE_SIZE || '2048x1152').split('x').map(Number);
const LARGE_PASSES = 4;

async function screenshot(page, name) {
  if (!shotDir) return;
  fs.mkdirSync(shotDir, { recursive: true });
  await page.screenshot({ path: path.join(shotDir, `preview-${name}.png`), fullPage: true });
}

// Opens the page, picks the example, lets `edit` change the spec, submits it through
// the form and returns the new job's id.
async function submitExample(page, baseUrl, edit) {
  await page.goto(`${baseUrl}/`);
  await page.waitForSelector(`#example-select option[value="${EXAMPLE}"]`, { state: 'attached' });
  await page.selectOption('#example-select', EXAMPLE);
  await waitFor(async () => (await page.inputValue('#spec')).includes('"lighting"'), { what: 'the example in the form' });
  const spec = JSON.parse(await page.inputValue('#spec'));
  edit(spec);
  await page.fill('#spec', JSON.stringify(spec, null, 2));
  await page.click('#submit-btn');
  await page.waitForFunction(() => /^#\/jobs\//.test(location.hash));
  return decodeURIComponent((await page.evaluate(() => location.hash)).replace('#/jobs/', ''));
}

async function hook(page) {
  return page.evaluate(() => {
    const h = window.tallyPreview;
    return { ...h, dropStream: undefined };
  });
}

// A JSON call to the server from the test (not the page).
async function call(baseUrl, method, url, body) {
  const init = { method, headers: {} };
  if (body !== undefined) { init.headers['Content-Type'] = 'application/json'; init.body = JSON.stringify(body); }
  const res = await fetch(`${baseUrl}${url}`, init);
  const text = await res.text();
  return { status: res.status, json: text ? JSON.parse(text) : null };
}

async function jobIds(baseUrl) {
  return (await call(baseUrl, 'GET', '/v1/jobs?limit=1000')).json.jobs.map((j) => j.id);
}

// Cancels (if unfinished) and deletes a job.
async function removeJob(baseUrl, id) {
  if ((await call(baseUrl, 'DELETE', `/v1/jobs/${id}`)).status === 204) return;
  await waitFor(async () => ['cancelled', 'failed', 'succeeded'].includes((await call(baseUrl, 'GET', `/v1/jobs/${id}`)).json.state),
    { what: `job ${id} to stop` });
  assert.equal((await call(baseUrl, 'DELETE', `/v1/jobs/${id}`)).status, 204);
}

// An integral that would run for an hour: the pilot predicts it, the tests stop it.
const LONG_SPEC = {
  kind: 'integrate', name: 'a long integral', seed: 5, integrand: { builtin: 'unit_disk' },
  domain: { type: 'box', lower: [-1, -1], upper: [1, 1] }, stop: { max_samples: 1e11, time_budget_s: 3600 },
};

// A smooth 1-D integral with a tight target and no estimator: plain MC would need
// billions of samples, so validate suggests the auto estimator (tests/e2e ValidateNames…).
const SMOOTH_SPEC = {
  kind: 'integrate', seed: 5, integrand: { expression: 'exp(-x*x)' },
  domain: { type: 'box', lower: [0], upper: [1] }, stop: { rel_error: 1e-5 },
};

// A cluster's GET /v1/workers answer (server/cluster/cluster_http.cpp), for the page alone.
const WORKERS = {
  executor: 'redis', redis: 'redis://10.0.0.5:6379', lease_seconds: 30, pools: { '': 2 },
  workers: [
    { name: 'render-node-with-a-rather-long-name-01', host: 'rack7-blade12.cluster.example.org', threads: 64,
      pools: [], last_heartbeat: '2026-12-03T16:00:00Z', seconds_since_heartbeat: 1.5, blocks_done: 123456,
      current_job: '0123456789abcdef' },
    { name: 'w2', host: 'h2', threads: 8, pools: [], last_heartbeat: '2026-12-03T16:00:00Z',
      seconds_since_heartbeat: 12, blocks_done: 7, current_job: null },
  ],
  results: { first: 0 },
};

// The spec of examples/preview_image.json at another size: 1 sample per pixel a pass
// (independent samples: the sobol sampler's replicates make a pass at least K spp).
async function sizedSpec(baseUrl, [w, h], tileSize, passes) {
  const spec = await (await fetch(`${baseUrl}${EXAMPLE}`)).json();
  spec.name = `${w}x${h}`;
  spec.sampler = 'independent';
  spec.scene.camera.resolution = [w, h];
  spec.query.tile_size = tileSize;
  spec.query.max_pass_spp = 1;
  spec.stop = { max_samples: passes };
  return spec;
}

// The page's canvas against the server's PNG of the job: the largest difference per
// channel over `samples` pixels (all of them when 0) and how many of those are lit.
async function canvasVsPng(page, baseUrl, id, samples = 0) {
  const png = decodePng(Buffer.from(await (await fetch(`${baseUrl}/v1/jobs/${id}/image.png`)).arrayBuffer()));
  const n = png.width * png.height;
  const picks = [];
  if (samples) {
    let r = 12345;  // a fixed LCG: the same pixels every run
    for (let i = 0; i < samples; ++i) { r = (r * 1103515245 + 12345) % 2147483648; picks.push(r % n); }
    picks.push(0, png.width - 1, n - png.width, n - 1);  // the corners
  }
  const canvas = await page.evaluate((idx) => {
    const c = document.getElementById('image');
    const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
    if (!idx.length) return { w: c.width, h: c.height, px: Array.from(d) };
    const px = [];
    for (const i of idx) px.push(d[4 * i], d[4 * i + 1], d[4 * i + 2], d[4 * i + 3]);
    return { w: c.width, h: c.height, px };
  }, picks);
  assert.equal(canvas.w, png.width);
  assert.equal(canvas.h, png.height);
  const idx = samples ? picks : [...Array(n).keys()];
  let worst = 0, lit = 0;
  idx.forEach((p, k) => {
    for (let c = 0; c < 3; ++c) worst = Math.max(worst, Math.abs(canvas.px[4 * k + c] - png.data[4 * p + c]));
    if (png.data[4 * p] + png.data[4 * p + 1] + png.data[4 * p + 2] > 0) lit++;
  });
  return { worst, lit, count: idx.length, width: png.width, height: png.height };
}

function assertConsecutive(passes, finalPass) {
  assert.ok(passes.length > 0, 'no progress events seen');
  for (let i = 1; i < passes.length; ++i) {
    assert.equal(passes[i], passes[i - 1] + 1,
      `passes must arrive once each and in order; got ${passes[i - 1]} then ${passes[i]} (all: ${passes.join(',')})`);
  }
  assert.equal(passes[passes.length - 1], finalPass, 'the last pass seen is the job\'s last pass');
}

describe('preview page', { concurrency: 1 }, () => {
  let server;
  let browser;

  before(async () => {
    assert.ok(serverBinary, 'set TALLY_SERVER to the tally-server binary');
    // A big replay buffer: the cut in the resume test may last Chromium's 3 s retry.
    // The resume test's job makes up to ~15k passes of ~13 events each in its 10 s budget on an
    // idle machine; the buffer must hold all of them so a cut never falls outside it.
    server = await startServer(serverBinary, ['--event-buffer', '400000']);
    browser = await launchBrowser(chromium);
  });

  after(async () => {
    if (browser) await browser.close();
    if (server) await server.stop();
  });

  test('serves the page, its assets and the examples with content types and caching headers', async () => {
    const index = await fetch(`${server.url}/`);
    assert.equal(index.status, 200);
    assert.match(index.headers.get('content-type'), /^text\/html/);
    assert.equal(index.headers.get('cache-control'), 'no-cache');
    const etag = index.headers.get('etag');
    assert.match(etag, /^"[0-9a-f]{16}"$/);
    const html = await index.text();
    const again = await fetch(`${server.url}/`, { headers: { 'If-None-Match': etag } });
    assert.equal(again.status, 304);

    const m = /src="(\/preview\/app\.js\?v=([0-9a-f]{16}))"/.exec(html);
    assert.ok(m, 'index.html links app.js with its content hash');
    const js = await fetch(`${server.url}${m[1]}`);
    assert.equal(js.status, 200);
    assert.match(js.headers.get('content-type'), /^text\/javascript/);
    assert.match(js.headers.get('cache-control'), /max-age=31536000/);
    assert.equal(js.headers.get('etag'), `"${m[2]}"`);
    const css = await fetch(`${server.url}/preview/style.css`);
    assert.match(css.headers.get('content-type'), /^text\/css/);
    assert.equal(css.headers.get('cache-control'), 'no-cache');

    const ex = await (await fetch(`${server.url}/examples/index.json`)).json();
    assert.ok(ex.examples.some((e) => e.url === EXAMPLE && e.image === true), JSON.stringify(ex));
    const missing = await fetch(`${server.url}/preview/nope.js`);
    assert.equal(missing.status, 404);
    assert.match(missing.headers.get('content-type'), /problem\+json/);
  });

  test('validates and submits a lighting job; the canvas equals the server\'s PNG', async () => {
    const page = await browser.context.newPage();
    const errors = [];
    page.on('pageerror', (e) => errors.push(String(e)));

    // Validate first: the plan and the pilot's prediction appear under the form.
    await page.goto(`${server.url}/`);
    await page.waitForSelector(`#example-select option[value="${EXAMPLE}"]`, { state: 'attached' });
    await page.selectOption('#example-select', EXAMPLE);
    await waitFor(async () => (await page.inputValue('#spec')).includes('"lighting"'), { what: 'the example' });
    await page.click('#validate-btn');
    await page.waitForFunction(() => document.getElementById('submit-result').textContent.includes('valid lighting job'),
      null, { timeout: 30000 });

    const id = await submitExample(page, server.url, (spec) => {
      spec.query.max_pass_spp = 4;
      spec.stop = { max_samples: 32 };  // 8 passes
    });
    await page.waitForFunction(() => window.tallyPreview.tileFetches > 0, null, { timeout: 30000 });
    await page.waitForFunction(() => window.tallyPreview.settled, null, { timeout: 240000 });
    await screenshot(page, 'finished');

    const status = await (await fetch(`${server.url}/v1/jobs/${id}`)).json();
    assert.equal(status.state, 'succeeded');
    const png = decodePng(Buffer.from(await (await fetch(`${server.url}/v1/jobs/${id}/image.png`)).arrayBuffer()));
    assert.equal(png.width, 64);
    assert.equal(png.height, 48);
    const canvas = await page.evaluate(() => {
      const c = document.getElementById('image');
      return { w: c.width, h: c.height, data: Array.from(c.getContext('2d').getImageData(0, 0, c.width, c.height).data) };
    });
    assert.equal(canvas.w, png.width);
    assert.equal(canvas.h, png.height);
    let worst = 0, nonBlack = 0;
    for (let i = 0; i < png.data.length; i += 4) {
      for (let c = 0; c < 3; ++c) worst = Math.max(worst, Math.abs(canvas.data[i + c] - png.data[i + c]));
      if (png.data[i] + png.data[i + 1] + png.data[i + 2] > 0) nonBlack++;
    }
    assert.ok(nonBlack > png.width * png.height / 4, `the image should not be mostly black (${nonBlack} lit pixels)`);
    assert.ok(worst <= 1, `canvas differs from the server's PNG by ${worst} levels`);

    const h = await hook(page);
    assertConsecutive(h.passesSeen, status.passes);
    // Only changed tiles: every fetch follows a tile event (plus one full draw when the
    // page opened on a job that had already made progress); several events for one
    // tile within 250 ms cost a single fetch.
    const tiles = 12;
    assert.ok(h.tileFetches <= h.tileEvents + tiles, `tile fetches ${h.tileFetches} vs tile events ${h.tileEvents}`);

    // The standard-error heat map, and the plan is on the page.
    await page.check('input[name=view][value=stderr]');
    await page.waitForFunction(() => !document.getElementById('heat-legend').hidden);
    assert.match(await page.textContent('#plan'), /"plan"|"direct"|"effects"|"shadow/);
    assert.deepEqual(errors, []);
    await page.close();
  });

  test('a job that ends before the event stream connects is drawn from its final status', async () => {
    // The race a loaded machine hits: the page reads the status while the job has no pass
    // yet, the job ends, and only then the event stream connects; it gets a snapshot
    // without tile events. The page must still draw every tile (from the status it reads
    // at the end). Forced here: the first status read is answered as "no pass yet" and
    // the event stream is held until the job has ended.
    const page = await browser.context.newPage();
    const errors = [];
    page.on('pageerror', (e) => errors.push(String(e)));
    let statusReads = 0;
    await page.route(/\/v1\/jobs\/[0-9a-f]+$/, async (route) => {
      if (route.request().method() !== 'GET' || statusReads++ > 0) return route.continue();
      const real = await route.fetch();
      const body = await real.json();
      Object.assign(body, { state: 'running', stop_reason: 'none', passes: 0, samples: 0 });
      return route.fulfill({ response: real, json: body });
    });
    await page.route(/\/v1\/jobs\/[0-9a-f]+\/events/, async (route) => {
      const id = /\/v1\/jobs\/([0-9a-f]+)\/events/.exec(route.request().url())[1];
      await waitFor(async () => (await (await fetch(`${server.url}/v1/jobs/${id}`)).json()).state === 'succeeded',
        { what: 'the job to end before its stream connects', timeout: 60000 });
      return route.continue();
    });
    const id = await submitExample(page, server.url, (spec) => {
      spec.query.max_pass_spp = 4;
      spec.stop = { max_samples: 16 };
    });
    await page.waitForFunction(() => window.tallyPreview.settled, null, { timeout: 60000 });
    const h = await hook(page);
    assert.ok(statusReads >= 2, `the status is read again at the end (${statusReads} reads)`);
    assert.equal(h.tileEvents, 0, 'the snapshot of an ended job has no tile events');
    assert.ok(h.tileFetches >= 12, `every tile is fetched once (${h.tileFetches} fetches)`);
    const png = decodePng(Buffer.from(await (await fetch(`${server.url}/v1/jobs/${id}/image.png`)).arrayBuffer()));
    const canvas = await page.evaluate(() => {
      const c = document.getElementById('image');
      return Array.from(c.getContext('2d').getImageData(0, 0, c.width, c.height).data);
    });
    let worst = 0;
    for (let i = 0; i < png.data.length; i += 4) {
      for (let c = 0; c < 3; ++c) worst = Math.max(worst, Math.abs(canvas[i + c] - png.data[i + c]));
    }
    assert.ok(worst <= 1, `canvas differs from the server's PNG by ${worst} levels`);
    assert.deepEqual(errors, []);
    await page.close();
  });

  test('the dashboard fits 1280 and 390 px: names, a readable prediction, downloads and delete', async () => {
    const page = await browser.context.newPage();
    await page.setViewportSize({ width: 1280, height: 900 });
    // The workers panel too, as a cluster's server shows it (long names, six columns).
    await page.route('**/v1/workers', (route) => route.fulfill({ json: WORKERS }));
    try {
      const name = 'dashboard check: a long job name that must wrap or be cut, never widen the page';
      const id = await submitExample(page, server.url, (spec) => { spec.name = name; spec.stop = { max_samples: 2 }; });
      await waitFor(async () => (await hook(page)).settled, { what: 'the job to finish and be drawn', timeout: 60000 });
      assert.equal(await page.textContent('#job-name'), name);
      await waitFor(async () => (await page.$(`#jobs tr[data-id="${id}"] td.name`)) !== null, { what: 'the job in the list' });
      assert.equal(await page.getAttribute(`#jobs tr[data-id="${id}"] td.name`, 'title'), name);
      // The download buttons name the server's files of this job.
      for (const [sel, magic] of [['#download-exr', [0x76, 0x2f, 0x31, 0x01]], ['#download-png', [0x89, 0x50, 0x4e, 0x47]]]) {
        assert.equal(await page.isVisible(sel), true, `${sel} is shown for an image job`);
        const res = await fetch(new URL(await page.getAttribute(sel, 'href'), server.url));
        assert.equal(res.status, 200);
        assert.deepEqual([...new Uint8Array(await res.arrayBuffer()).subarray(0, 4)], magic, sel);
      }
      const stats = await page.textContent('#stats');
      assert.match(stats, /spp \(samples per pixel\)/);
      assert.match(stats, /spp\/s/);
      assert.doesNotMatch(stats, /samples\/s/);
      // Validate shows the prediction as rows, not JSON.
      await page.click('#validate-btn');
      await page.waitForSelector('#prediction', { timeout: 60000 });
      const prediction = await page.textContent('#prediction');
      assert.match(prediction, /stops by/);
      assert.doesNotMatch(prediction, /[{}]/);

      assert.equal(await page.isVisible('#workers-panel'), true, 'the workers panel is part of the layout checked');
      const shots = shotDir || fs.mkdtempSync(path.join(process.env.TMPDIR || '/tmp', 'tally-dashboard-'));
      for (const width of [1280, 390]) {
        await page.setViewportSize({ width, height: 900 });
        await sleep(200);
        const o = await page.evaluate(() => {
          const over = [];
          for (const e of document.querySelectorAll('header, main, .panel, #jobs, #workers, #stats, #prediction, #plot, #image, .job-head .buttons > *, #submit-form .buttons > *')) {
            const r = e.getBoundingClientRect();
            if (r.width > 0 && (r.right > window.innerWidth + 0.5 || r.left < -0.5)) {
              over.push(`${e.id || e.className || e.tagName}: ${Math.round(r.left)}..${Math.round(r.right)}`);
            }
          }
          // Panels that scroll inside (the job list, the plan) must not have to either.
          for (const e of document.querySelectorAll('#jobs-panel, #workers-panel, #stats, #prediction')) {
            if (e.scrollWidth > e.clientWidth + 1) over.push(`${e.id} scrolls: ${e.scrollWidth} > ${e.clientWidth}`);
          }
          return { scrollWidth: document.documentElement.scrollWidth, innerWidth: window.innerWidth, over };
        });
        assert.deepEqual(o.over, [], `at ${width} px these stick out of the window`);
        assert.ok(o.scrollWidth <= o.innerWidth, `at ${width} px the page is ${o.scrollWidth} px wide`);
        // A full-page screenshot is as wide as the page: the window's width when nothing overflows.
        const file = path.join(shots, `preview-dashboard-${width}.png`);
        await page.screenshot({ path: file, fullPage: true });
        assert.equal(decodePng(fs.readFileSync(file)).width, width, `the ${width} px screenshot (${file})`);
      }

      // Delete: the job is gone from the server and from the list.
      await page.click('#delete-btn');
      await waitFor(async () => (await page.$(`#jobs tr[data-id="${id}"]`)) === null, { what: 'the row to go' });
      assert.equal((await fetch(`${server.url}/v1/jobs/${id}`)).status, 404);
    } finally {
      await page.close();
    }
  });

  test('validate names a faster estimator for a smooth integral; "use it" puts it into the spec', async () => {
    const page = await browser.context.newPage();
    const errors = [];
    page.on('pageerror', (e) => errors.push(String(e)));
    try {
      await page.goto(`${server.url}/`);
      await page.setViewportSize({ width: 390, height: 900 });
      await page.fill('#spec', JSON.stringify(SMOOTH_SPEC, null, 2));
      await page.click('#validate-btn');
      await page.waitForSelector('#suggestion', { timeout: 60000 });
      const text = await page.textContent('#suggestion');
      const m = text.match(/would choose (\w+).*about ([\d.,]+)(k|M|G)?× fewer integrand evaluations/);
      assert.ok(m, `the suggestion names an estimator and the saving: ${text}`);
      assert.notEqual(m[1], 'uniform');
      const ratio = Number(m[2].replace(/,/g, '')) * ({ k: 1e3, M: 1e6, G: 1e9 }[m[3]] || 1);
      assert.ok(ratio > 100, `about ${ratio}x fewer evaluations (the server's e2e test: > 100)`);
      const box = await page.evaluate(() => document.getElementById('suggestion').getBoundingClientRect().right);
      assert.ok(box <= 390.5, `the suggestion fits a 390 px window (right edge ${box})`);

      await page.click('#use-suggestion');
      await waitFor(async () => JSON.parse(await page.inputValue('#spec')).estimator?.type === 'auto',
        { what: 'the estimator in the spec' });
      // The spec is validated again: it names its estimator now, so no suggestion is left.
      await page.waitForFunction(() => document.getElementById('submit-result').textContent.includes('valid') &&
        !document.getElementById('suggestion'), null, { timeout: 60000 });
      const spec = JSON.parse(await page.inputValue('#spec'));
      assert.deepEqual({ ...spec, estimator: undefined }, { ...SMOOTH_SPEC, estimator: undefined }, 'the rest is untouched');
      assert.deepEqual(errors, []);
    } finally {
      await page.close();
    }
  });

  test('the priority control changes a running job\'s priority; Requeue runs a cancelled job again', async () => {
    const page = await browser.context.newPage();
    const errors = [];
    page.on('pageerror', (e) => errors.push(String(e)));
    const made = [];
    try {
      const sub = await call(server.url, 'POST', '/v1/jobs?priority=-2', LONG_SPEC);
      assert.equal(sub.status, 202);
      const id = sub.json.id;
      made.push(id);
      await page.goto(`${server.url}/#/jobs/${id}`);
      await waitFor(async () => (await page.inputValue('#priority-select')) === '-2', { what: 'the job\'s priority on the page' });
      assert.equal(await page.isDisabled('#priority-btn'), false);
      assert.equal(await page.isHidden('#requeue-btn'), true, 'no requeue for a running job');
      await page.selectOption('#priority-select', '3');
      await page.click('#priority-btn');
      await waitFor(async () => (await call(server.url, 'GET', `/v1/jobs/${id}`)).json.priority === 3,
        { what: 'the server to hold priority 3' });
      assert.equal((await call(server.url, 'GET', '/v1/jobs')).json.jobs.find((j) => j.id === id).priority, 3);
      assert.equal(await page.inputValue('#priority-select'), '3', 'the page shows what the server answered');

      // Cancelled: the priority is fixed, Requeue appears and submits the spec again.
      await page.click('#cancel-btn');
      await page.waitForFunction(() => !document.getElementById('requeue-btn').hidden, null, { timeout: 30000 });
      assert.equal(await page.isDisabled('#priority-btn'), true);
      assert.equal((await call(server.url, 'PATCH', `/v1/jobs/${id}`, { priority: 1 })).status, 409);
      const before = await jobIds(server.url);
      await page.click('#requeue-btn');
      await page.waitForFunction((old) => /^#\/jobs\//.test(location.hash) && !location.hash.endsWith(old), id);
      const requeued = decodeURIComponent((await page.evaluate(() => location.hash)).replace('#/jobs/', ''));
      made.push(requeued);
      assert.ok(!before.includes(requeued), 'a new job');
      assert.deepEqual((await jobIds(server.url)).filter((j) => !before.includes(j)), [requeued], 'exactly one job more');
      const a = (await call(server.url, 'GET', `/v1/jobs/${id}`)).json;
      const b = (await call(server.url, 'GET', `/v1/jobs/${requeued}`)).json;
      assert.deepEqual(b.spec, a.spec, 'the same spec (name, seed, stop rule)');
      assert.equal(b.spec.name, LONG_SPEC.name);
      assert.equal(b.priority, 3, 'at the priority the job had');
      assert.ok(['queued', 'running'].includes(b.state), b.state);
      assert.equal(a.state, 'cancelled', 'the old job stays as it was');
      await page.waitForFunction((old) => !document.getElementById('job-origin').hidden &&
        document.getElementById('job-origin-link').getAttribute('href') === `#/jobs/${old}`, id);
      assert.equal(await page.textContent('#job-origin'), `a requeue of job ${id}`);
      assert.equal(await page.textContent('#job-name'), LONG_SPEC.name);
      assert.deepEqual(errors, []);
    } finally {
      for (const id of made) await removeJob(server.url, id);
      await page.close();
    }
  });

  test('Submit asks before a job predicted to compute longer than the threshold', async () => {
    const page = await browser.context.newPage();
    const errors = [];
    page.on('pageerror', (e) => errors.push(String(e)));
    let made = null;
    try {
      await page.goto(`${server.url}/`);
      await page.waitForSelector('#submit-btn');
      assert.equal(await page.inputValue('#warn-seconds'), '60', 'the CLI\'s --warn-seconds default');
      await page.fill('#spec', JSON.stringify(LONG_SPEC, null, 2));
      const before = await jobIds(server.url);
      await page.click('#submit-btn');
      await page.waitForSelector('#confirm-submit:not([hidden])', { timeout: 60000 });
      assert.match(await page.textContent('#confirm-text'), /^The pilot predicts .* of compute \(stops by [a-z_]+\), more than 1 min 0 s\. Submit it\?$/);
      await page.click('#confirm-no');
      await page.waitForSelector('#confirm-submit', { state: 'hidden' });
      assert.equal(await page.textContent('#submit-result'), 'not submitted');
      assert.deepEqual(await jobIds(server.url), before, 'no job was submitted');

      await page.click('#submit-btn');
      await page.waitForSelector('#confirm-submit:not([hidden])', { timeout: 60000 });
      await page.click('#confirm-yes');
      await page.waitForFunction(() => /^#\/jobs\//.test(location.hash));
      made = decodeURIComponent((await page.evaluate(() => location.hash)).replace('#/jobs/', ''));
      assert.deepEqual((await jobIds(server.url)).filter((j) => !before.includes(j)), [made]);
      assert.deepEqual((await call(server.url, 'GET', `/v1/jobs/${made}`)).json.spec, LONG_SPEC);
      await removeJob(server.url, made);
      const asked = made;
      made = null;

      // Under the threshold: submitted without a question.
      await page.fill('#spec', JSON.stringify({ ...LONG_SPEC, stop: { max_samples: 1000 } }));
      await page.click('#submit-btn');
      await page.waitForFunction((old) => /^#\/jobs\//.test(location.hash) && !location.hash.endsWith(old), asked);
      made = decodeURIComponent((await page.evaluate(() => location.hash)).replace('#/jobs/', ''));
      assert.equal(await page.isHidden('#confirm-submit'), true);
      assert.equal((await call(server.url, 'GET', `/v1/jobs/${made}`)).json.spec.stop.max_samples, 1000);
      assert.deepEqual(errors, []);
    } finally {
      if (made) await removeJob(server.url, made);
      await page.close();
    }
  });

  test('the workers panel: hidden in process, the cluster\'s workers when the server has them', async () => {
    const direct = await call(server.url, 'GET', '/v1/workers');
    assert.deepEqual(direct.json, { executor: 'in_process', workers: [] });
    const page = await browser.context.newPage();
    try {
      await page.goto(`${server.url}/`);
      await page.waitForSelector('#jobs-panel');
      await page.waitForResponse((r) => r.url().endsWith('/v1/workers'));
      await sleep(100);
      assert.equal(await page.isHidden('#workers-panel'), true, 'in process: no panel');

      await page.route('**/v1/workers', (route) => route.fulfill({ json: WORKERS }));
      await page.waitForSelector('#workers-panel:not([hidden])', { timeout: 10000 });  // the next 2 s poll
      const rows = await page.$$eval('#workers tbody tr', (trs) => trs.map((tr) => [...tr.cells].map((c) => c.textContent)));
      assert.deepEqual(rows, [
        ['render-node-with-a-rather-long-name-01', 'rack7-blade12.cluster.example.org', '64', '1.5 s ago', '123k', '01234567'],
        ['w2', 'h2', '8', '12 s ago', '7', 'idle'],
      ]);
      assert.equal(await page.getAttribute('#workers tbody tr:first-child a', 'href'), '#/jobs/0123456789abcdef');
      assert.equal(await page.textContent('#workers-summary'), '2 workers, 72 threads · redis://10.0.0.5:6379');
      assert.equal(await page.isHidden('#workers-empty'), true);
      // A user the route refuses (403): hidden again.
      await page.unroute('**/v1/workers');
      await page.route('**/v1/workers', (route) => route.fulfill({ status: 403, contentType: 'application/problem+json',
        body: JSON.stringify({ type: 'about:blank', title: 'Forbidden', status: 403, detail: 'admin only' }) }));
      await page.waitForSelector('#workers-panel', { state: 'hidden', timeout: 10000 });
    } finally {
      await page.close();
    }
  });

  test('a finished image job\'s convergence plot is drawn from the trace the server keeps', async () => {
    const spec = await (await fetch(`${server.url}${EXAMPLE}`)).json();
    spec.query.max_pass_spp = 4;
    spec.stop = { max_samples: 32 };  // 8 passes
    const sub = await call(server.url, 'POST', '/v1/jobs', spec);
    const id = sub.json.id;
    await waitFor(async () => (await call(server.url, 'GET', `/v1/jobs/${id}`)).json.state === 'succeeded',
      { what: 'the image job to finish', timeout: 120000 });
    const status = (await call(server.url, 'GET', `/v1/jobs/${id}`)).json;
    const page = await browser.context.newPage();
    try {
      await page.goto(`${server.url}/#/jobs/${id}`);  // opened after the end: no live progress seen
      await page.waitForFunction(() => window.tallyPreview.settled, null, { timeout: 60000 });
      const h = await hook(page);
      // The stream of a finished job replays its last progress only (same compute time
      // as the trace's last point: no point added).
      assert.ok(h.passesSeen.length <= 1, `passes seen: ${h.passesSeen}`);
      const trace = status.trace.filter((t) => t[0] > 0 && t[3] > 0);
      assert.ok(trace.length >= 2, `the server keeps the image's trace (${status.trace.length} points)`);
      assert.equal(h.points.length, trace.length);
      const z = status.error.abs / trace[trace.length - 1][3];
      assert.ok(z > 1.9 && z < 2.1, `the CI half-width over the trace's σ/√n is the 95% critical value (${z})`);
      for (let i = 0; i < trace.length; ++i) {
        assert.equal(h.points[i][0], trace[i][0]);
        assert.ok(Math.abs(h.points[i][1] - trace[i][3] * z) <= 1e-12 * h.points[i][1], `point ${i}`);
      }
      assert.ok(Math.abs(h.points[trace.length - 1][1] - status.error.abs) <= 1e-12 * status.error.abs,
        'the last point is the final CI half-width');
      // The curve is drawn (the plot's blue), not a note.
      const blue = await page.evaluate(() => {
        const c = document.getElementById('plot');
        const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
        let n = 0;
        for (let i = 0; i < d.length; i += 4) if (d[i] === 47 && d[i + 1] === 111 && d[i + 2] === 219) n++;
        return n;
      });
      assert.ok(blue > 50, `${blue} pixels of the curve`);
    } finally {
      await page.close();
      await removeJob(server.url, id);
    }
  });

  test('a cut connection and a dropped EventSource resume with no lost or duplicated pass', async () => {
    const proxy = await startProxy(server.port);
    const page = await browser.context.newPage();
    const errors = [];
    page.on('pageerror', (e) => errors.push(String(e)));
    try {
      const id = await submitExample(page, proxy.url, (spec) => {
        spec.seed = 11;
        // Many short passes for a few seconds: the cuts below land mid-job whatever
        // the machine's speed.
        spec.query.max_pass_spp = 1;
        spec.stop = { time_budget_s: 10 };
      });
      await page.waitForFunction(() => window.tallyPreview.passesSeen.length >= 3, null, { timeout: 30000 });
      await sleep(1500);  // some history for the plot
      if (!(await hook(page)).ended) await screenshot(page, 'running');

      // 1. The network drops every connection: Chromium's EventSource reconnects by
      //    itself and sends Last-Event-ID.
      assert.ok(proxy.cut() > 0, 'the proxy had open connections to cut');
      await page.waitForFunction(() => window.tallyPreview.reconnects >= 1, null, { timeout: 10000 });
      // Passes that arrive from now on came over the new connection.
      const atError = (await hook(page)).passesSeen.length;
      // Three more passes, or the end of the job (its 10 s budget may run out first on a
      // loaded machine: the reconnect alone waits for EventSource's retry delay).
      await page.waitForFunction((n) => window.tallyPreview.passesSeen.length > n + 2 || window.tallyPreview.ended,
        atError, { timeout: 60000 });
      assert.equal(await page.isHidden('#job-message'), true, 'the "reconnecting" note is gone');

      // 2. The page loses its EventSource and opens a new one from the last id.
      const mid = await hook(page);
      if (!mid.ended) {
        await page.evaluate(() => window.tallyPreview.dropStream());
        await sleep(600);
      }
      await page.waitForFunction(() => window.tallyPreview.settled, null, { timeout: 240000 });

      const status = await (await fetch(`${server.url}/v1/jobs/${id}`)).json();
      assert.equal(status.state, 'succeeded');
      await page.check('input[name=view][value=stderr]');
      await sleep(400);  // the progress bar's transition
      await screenshot(page, 'stderr');
      const h = await hook(page);
      assert.ok(h.reconnects >= (mid.ended ? 1 : 2), `reconnects: ${h.reconnects}`);
      assertConsecutive(h.passesSeen, status.passes);
      const ids = h.eventIds.map(Number);
      for (let i = 1; i < ids.length; ++i) assert.ok(ids[i] >= ids[i - 1], `event ids go back: ${ids[i - 1]} -> ${ids[i]}`);
      assert.deepEqual(errors, []);
    } finally {
      await page.close();
      await proxy.close();
    }
  });
  test('a pass over more than 64 tiles sends one `tiles` event; the tile path fetches its tiles', async () => {
    // 320×240 in 16 px tiles: 300 tiles (a small image: the tile path), all refined every pass.
    const page = await browser.context.newPage();
    const errors = [];
    page.on('pageerror', (e) => errors.push(String(e)));
    const pngRequests = [];
    page.on('request', (r) => { if (/\/image\.png$/.test(new URL(r.url()).pathname)) pngRequests.push(r.url()); });
    let id = null;
    try {
      await page.goto(`${server.url}/`);
      await page.waitForSelector('#jobs-panel');
      const sub = await call(server.url, 'POST', '/v1/jobs', await sizedSpec(server.url, [320, 240], 16, 3));
      assert.equal(sub.status, 202);
      id = sub.json.id;
      await page.evaluate((j) => { location.hash = `#/jobs/${j}`; }, id);
      await page.waitForFunction(() => window.tallyPreview.settled, null, { timeout: 60000 });
      const status = (await call(server.url, 'GET', `/v1/jobs/${id}`)).json;
      assert.equal(status.result.image.tiles, 300);
      const h = await hook(page);
      assert.equal(h.large, false);
      assert.ok(h.tilesEvents >= 1, `tiles events: ${h.tilesEvents}`);
      assert.equal(h.tileEvents, 0, 'no per-tile events above 64 tiles a pass');
      // Every tile of a `tiles` event is fetched (plus a full draw when the page opened on
      // a job that already had a pass), a tile at most once per flush.
      assert.ok(h.tileFetches >= 300 && h.tileFetches <= 300 * (h.tilesEvents + 1), `tile fetches ${h.tileFetches}`);
      assert.deepEqual(pngRequests, [], 'a small image is drawn from its tiles');
      const cmp = await canvasVsPng(page, server.url, id);
      assert.ok(cmp.lit > cmp.count / 4, `the image should not be mostly black (${cmp.lit} lit pixels)`);
      assert.ok(cmp.worst <= 1, `canvas differs from the server's PNG by ${cmp.worst} levels`);
      assert.deepEqual(errors, []);
    } finally {
      await page.close();
      if (id) await removeJob(server.url, id);
    }
  });

  test('a large image is drawn from image.png, fits, shows 1:1, pans, and the page stays responsive', async () => {
    const t0 = Date.now();
    const [W, H] = LARGE_SIZE;
    const page = await browser.context.newPage();
    const errors = [];
    page.on('pageerror', (e) => errors.push(String(e)));
    const requests = { png: 0, tiles: 0 };
    page.on('request', (r) => {
      const u = new URL(r.url()).pathname;
      if (/\/image\.png$/.test(u)) requests.png++;
      else if (/\/tiles\/\d+$/.test(u)) requests.tiles++;
    });
    // The longest main-thread task while the job runs (Long Tasks API: tasks over 50 ms).
    await page.addInitScript(() => {
      window.__longest = { ms: 0, supported: false };
      if ((PerformanceObserver.supportedEntryTypes || []).includes('longtask')) {
        window.__longest.supported = true;
        new PerformanceObserver((list) => {
          for (const e of list.getEntries()) window.__longest.ms = Math.max(window.__longest.ms, e.duration);
        }).observe({ type: 'longtask' });
      }
    });
    let id = null;
    try {
      await page.goto(`${server.url}/`);
      await page.waitForSelector('#jobs-panel');
      await page.evaluate(() => { window.__longest.ms = 0; });  // the page's own load does not count
      const sub = await call(server.url, 'POST', '/v1/jobs', await sizedSpec(server.url, LARGE_SIZE, 32, LARGE_PASSES));
      assert.equal(sub.status, 202, JSON.stringify(sub.json));
      id = sub.json.id;
      await page.evaluate((j) => { location.hash = `#/jobs/${j}`; }, id);

      // While the job runs: a round trip into the page every 100 ms. A main thread busy
      // with a long task (a JSON parse of thousands of tiles, a 33 MB getImageData) would
      // hold it for seconds; drawing a decoded bitmap holds it for tens of ms.
      let worstTrip = 0, trips = 0;
      for (;;) {
        const a = Date.now();
        const h = await page.evaluate(() => ({ settled: window.tallyPreview.settled, draws: window.tallyPreview.imageDraws }));
        worstTrip = Math.max(worstTrip, Date.now() - a);
        trips++;
        if (h.settled) break;
        assert.ok(Date.now() - t0 < 120000, 'the large job should be drawn within 2 min');
        await sleep(100);
      }
      const runMs = Date.now() - t0;

      const status = (await call(server.url, 'GET', `/v1/jobs/${id}`)).json;
      assert.equal(status.state, 'succeeded');
      assert.ok(status.result.image.tiles > 1024, `${status.result.image.tiles} tiles`);
      const h = await hook(page);
      assert.equal(h.large, true);
      assert.ok(h.tilesEvents >= 1, `tiles events: ${h.tilesEvents}`);
      assert.equal(h.tileEvents, 0, 'a pass over the whole image sends one `tiles` event, no `tile` events');
      assert.equal(requests.tiles, 0, 'no per-tile JSON for a large image');
      assert.equal(h.tileFetches, 0);
      assert.ok(requests.png >= 1 && requests.png <= status.passes + 2,
        `image.png requests: ${requests.png} for ${status.passes} passes`);
      assert.ok(h.imageDraws >= 1 && h.imageDraws <= requests.png);

      // Responsive: the bound is generous (a 2-core machine that renders the job on both
      // cores, in a headless browser without a GPU); the old tile path stalled for many
      // seconds on this image.
      const longest = await page.evaluate(() => window.__longest);
      assert.ok(worstTrip < 1000, `a round trip into the page took ${worstTrip} ms`);
      if (longest.supported) assert.ok(longest.ms < 1000, `the longest main-thread task took ${longest.ms} ms`);

      // The standard-error map is off, and the page says so.
      assert.equal(await page.isDisabled('#view-stderr'), true);
      assert.match(await page.textContent('#large-note'), /standard-error map is not shown/);

      // Fit (the default): the whole image within the panel and the window.
      const geom = () => page.evaluate(() => {
        const c = document.getElementById('image'), v = document.getElementById('image-view');
        const r = c.getBoundingClientRect(), box = document.getElementById('image-box').getBoundingClientRect();
        return { w: c.width, h: c.height, cw: r.width, ch: r.height, boxW: box.width, innerH: window.innerHeight,
                 dpr: window.devicePixelRatio, left: v.scrollLeft, top: v.scrollTop,
                 vw: v.clientWidth, vh: v.clientHeight, sw: v.scrollWidth, sh: v.scrollHeight,
                 vr: v.getBoundingClientRect().toJSON() };
      });
      let g = await geom();
      assert.equal(h.zoom, 'fit');
      assert.deepEqual([g.w, g.h], [W, H], 'the canvas has the image\'s resolution');
      assert.ok(g.cw <= g.boxW + 0.5 && g.ch <= 0.7 * g.innerH + 0.5, `fit: ${g.cw}×${g.ch} in ${g.boxW}×${0.7 * g.innerH}`);
      assert.ok(Math.abs(g.cw / g.ch - W / H) < 0.01, 'fit keeps the aspect ratio');

      // 1:1: one image pixel per device pixel, in a view that scrolls.
      await page.click('#zoom-one');
      g = await geom();
      assert.equal((await hook(page)).zoom, '1:1');
      assert.ok(Math.abs(g.cw * g.dpr - W) < 0.5 && Math.abs(g.ch * g.dpr - H) < 0.5, `1:1: ${g.cw}×${g.ch} at dpr ${g.dpr}`);
      assert.ok(g.sw > g.vw && g.sh > g.vh, 'the view scrolls at 1:1');
      assert.ok(g.vw <= g.boxW + 0.5, 'and stays inside the panel');
      // A mouse drag pans: dragging left and up shows what lies right and below.
      const before = { left: g.left, top: g.top };
      const x = g.vr.x + g.vr.width / 2, y = g.vr.y + g.vr.height / 2;
      await page.mouse.move(x, y);
      await page.mouse.down();
      await page.mouse.move(x - 120, y - 80, { steps: 5 });
      await page.mouse.up();
      g = await geom();
      assert.ok(Math.abs(g.left - before.left - 120) <= 1 && Math.abs(g.top - before.top - 80) <= 1,
        `the drag panned from ${JSON.stringify(before)} to ${g.left},${g.top}`);
      await page.click('#zoom-fit');
      g = await geom();
      assert.ok(g.cw <= g.boxW + 0.5, 'back to fit');

      // The final canvas is the server's PNG (±1 at 20,000 pixels and the corners).
      const cmp = await canvasVsPng(page, server.url, id, 20000);
      assert.ok(cmp.lit > cmp.count / 4, `the image should not be mostly black (${cmp.lit} of ${cmp.count} lit)`);
      assert.ok(cmp.worst <= 1, `canvas differs from the server's PNG by ${cmp.worst} levels`);
      assert.deepEqual(errors, []);
      console.log(`# large image ${W}x${H}: ${status.passes} passes, ${requests.png} image.png requests, ` +
        `job drawn in ${runMs} ms, worst round trip ${worstTrip} ms over ${trips}, ` +
        `longest task ${longest.supported ? `${Math.round(longest.ms)} ms` : 'n/a'}, test ${Date.now() - t0} ms`);
    } finally {
      await page.close();
      if (id) await removeJob(server.url, id);
    }
  });
});
