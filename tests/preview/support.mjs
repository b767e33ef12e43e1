// Helpers for the browser tests: a real tally-server on an ephemeral port, a TCP
// proxy whose connections the test can cut, a PNG decoder and the Chromium launch.
import { spawn } from 'node:child_process';
import fs from 'node:fs';
import net from 'node:net';
import os from 'node:os';
import path from 'node:path';
import zlib from 'node:zlib';

export const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

export async function waitFor(fn, { timeout = 30000, interval = 50, what = 'condition' } = {}) {
  const t0 = Date.now();
  for (;;) {
    const v = await fn();
    if (v) return v;
    if (Date.now() - t0 > timeout) throw new Error(`timed out after ${timeout} ms waiting for ${what}`);
    await sleep(interval);
  }
}

// Starts `binary` on 127.0.0.1 with port 0 and a fresh data dir; resolves once it listens.
export async function startServer(binary, extraArgs = []) {
  const dir = fs.mkdtempSync(path.join(os.tmpdir(), 'tally-preview-'));
  const portFile = path.join(dir, 'port');
  const args = ['--listen', '127.0.0.1:0', '--data-dir', path.join(dir, 'data'), '--port-file', portFile,
                '--workers', '2', ...extraArgs];
  const proc = spawn(binary, args, { stdio: ['ignore', 'pipe', 'pipe'] });
  let log = '';
  proc.stdout.on('data', (d) => { log += d; });
  proc.stderr.on('data', (d) => { log += d; });
  let exited = null;
  proc.on('exit', (code, sig) => { exited = { code, sig }; });
  await waitFor(() => {
    if (exited) throw new Error(`tally-server exited early (${JSON.stringify(exited)}):\n${log}`);
    return fs.existsSync(portFile);
  }, { timeout: 20000, what: 'tally-server to listen' });
  const port = Number(fs.readFileSync(portFile, 'utf8').trim());
  return {
    port,
    url: `http://127.0.0.1:${port}`,
    log: () => log,
    async stop() {
      if (!exited) {
        proc.kill('SIGTERM');
        await waitFor(() => exited, { timeout: 10000, what: 'tally-server to exit' }).catch(() => proc.kill('SIGKILL'));
      }
      fs.rmSync(dir, { recursive: true, force: true });
    },
  };
}

// A TCP proxy in front of the server: cut() destroys every open connection, as a
// flaky network or a restarting load balancer would.
export async function startProxy(targetPort) {
  const sockets = new Set();
  const server = net.createServer((client) => {
    const upstream = net.connect(targetPort, '127.0.0.1');
    const pair = [client, upstream];
    for (const s of pair) {
      sockets.add(s);
      s.on('error', () => {});
      s.on('close', () => { sockets.delete(s); for (const o of pair) o.destroy(); });
    }
    client.pipe(upstream);
    upstream.pipe(client);
  });
  await new Promise((r) => server.listen(0, '127.0.0.1', r));
  return {
    port: server.address().port,
    url: `http://127.0.0.1:${server.address().port}`,
    cut() { const n = sockets.size; for (const s of [...sockets]) s.destroy(); return n; },
    close() { for (const s of sockets) s.destroy(); return new Promise((r) => server.close(r)); },
  };
}

// Decodes an 8-bit, non-interlaced PNG (grey, RGB, grey+alpha or RGBA) into RGBA.
export function decodePng(buf) {
  const sig = Buffer.from([137, 80, 78, 71, 13, 10, 26, 10]);
  if (!buf.subarray(0, 8).equals(sig)) throw new Error('not a PNG');
  let off = 8, width = 0, height = 0, depth = 0, ctype = 0, interlace = 0;
  const idat = [];
  while (off < buf.length) {
    const len = buf.readUInt32BE(off);
    const type = buf.toString('latin1', off + 4, off + 8);
    const data = buf.subarray(off + 8, off + 8 + len);
    if (type === 'IHDR') {
      width = data.readUInt32BE(0); height = data.readUInt32BE(4);
      depth = data[8]; ctype = data[9]; interlace = data[12];
    } else if (type === 'IDAT') {
      idat.push(data);
    } else if (type === 'IEND') {
      break;
    }
    off += 12 + len;
  }
  if (depth !== 8 || interlace !== 0) throw new Error(`unsupported PNG: depth ${depth}, interlace ${interlace}`);
  const channels = { 0: 1, 2: 3, 4: 2, 6: 4 }[ctype];
  if (!channels) throw new Error(`unsupported PNG colour type ${ctype}`);
  const raw = zlib.inflateSync(Buffer.concat(idat));
  const stride = width * channels;
  const out = new Uint8Array(width * height * 4);
  let prev = new Uint8Array(stride);
  for (let y = 0; y < height; ++y) {
    const filter = raw[y * (stride + 1)];
    const line = Uint8Array.from(raw.subarray(y * (stride + 1) + 1, (y + 1) * (stride + 1)));
    for (let i = 0; i < stride; ++i) {
      const a = i >= channels ? line[i - channels] : 0, b = prev[i], c = i >= channels ? prev[i - channels] : 0;
      let p;
      switch (filter) {
        case 0: p = 0; break;
        case 1: p = a; break;
        case 2: p = b; break;
        case 3: p = (a + b) >> 1; break;
        case 4: {
          const pa = Math.abs(b - c), pb = Math.abs(a - c), pc = Math.abs(a + b - 2 * c);
          p = pa <= pb && pa <= pc ? a : pb <= pc ? b : c;
          break;
        }
        default: throw new Error(`bad PNG filter ${filter}`);
      }
      line[i] = (line[i] + p) & 255;
    }
    for (let x = 0; x < width; ++x) {
      const s = line.subarray(x * channels, (x + 1) * channels), o = 4 * (y * width + x);
      if (channels <= 2) { out[o] = out[o + 1] = out[o + 2] = s[0]; out[o + 3] = channels === 2 ? s[1] : 255; }
      else { out[o] = s[0]; out[o + 1] = s[1]; out[o + 2] = s[2]; out[o + 3] = channels === 4 ? s[3] : 255; }
    }
    prev = line;
  }
  return { width, height, data: out };
}

// Debian's chromium, headless, with a fresh profile directory.
export async function launchBrowser(chromiumModule) {
  const executablePath = process.env.CHROMIUM || '/usr/bin/chromium';
  const userDataDir = fs.mkdtempSync(path.join(os.tmpdir(), 'tally-chromium-'));
  const context = await chromiumModule.launchPersistentContext(userDataDir, {
    executablePath,
    headless: true,
    args: ['--headless', '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
           '--disable-background-networking', '--disable-component-update', '--disable-sync'],
    viewport: { width: 1280, height: 900 },
  });
  return {
    context,
    async close() {
      await context.close();
      fs.rmSync(userDataDir, { recursive: true, force: true });
    },
  };
}
