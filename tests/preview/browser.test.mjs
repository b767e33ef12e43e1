// The preview page in a real browser (Debian chromium, headless, via playwright-core)
// against a real tally-server: the form submits a lighting image job from examples/,
// the canvas is filled tile by tile from the event stream and must equal the
// server's PNG of the finished job (±1 per channel); a cut connection and a dropped
// EventSource must resume with every pass seen exactly once.
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

      const shots = shotDir || fs.mkdtempSync(path.join(process.env.TMPDIR || '/tmp', 'tally-dashboard-'));
      for (const width of [1280, 390]) {
        await page.setViewportSize({ width, height: 900 });
        await sleep(200);
        const o = await page.evaluate(() => {
          const over = [];
          for (const e of document.querySelectorAll('header, main, .panel, #jobs, #stats, #prediction, #plot, #image, .job-head .buttons > *')) {
            const r = e.getBoundingClientRect();
            if (r.width > 0 && (r.right > window.innerWidth + 0.5 || r.left < -0.5)) {
              over.push(`${e.id || e.className || e.tagName}: ${Math.round(r.left)}..${Math.round(r.right)}`);
            }
          }
          // Panels that scroll inside (the job list, the plan) must not have to either.
          for (const e of document.querySelectorAll('#jobs-panel, #stats, #prediction')) {
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
});
