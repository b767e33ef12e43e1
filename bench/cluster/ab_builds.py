#!/usr/bin/env python3
# A/B of two builds of tally in cluster mode. Usage:
#   bench/cluster/ab_builds.py OLD_DIR NEW_DIR ROUNDS disk|image
# OLD_DIR and NEW_DIR each hold a tally-server and a tally-worker (copied from a build
# tree). Starts, per build, a redis-server (Unix socket in a temp dir), an in-process
# server (--workers 2), a cluster server and one worker (--threads 2) on 127.0.0.1
# ports 18100-18103, runs the job on the four in rotation (PAUSE seconds apart,
# default 0.6) and prints each build's cluster / in-process wall ratio (median and
# quartiles of the rounds) and new/old ratios. Needs nothing but python3.
import json, os, subprocess, sys, time, urllib.request, tempfile, signal, statistics
dirs = {"old": sys.argv[1], "new": sys.argv[2]}; rounds = int(sys.argv[3]); which = sys.argv[4]
tmp = tempfile.mkdtemp(prefix='ab')
procs = []
import atexit, shutil


def cleanup():
    for p in procs:
        p.kill()
        p.wait()
    shutil.rmtree(tmp, ignore_errors=True)


atexit.register(cleanup)
def spawn(args, log):
    p = subprocess.Popen(args, stdout=open(log, 'w'), stderr=subprocess.STDOUT); procs.append(p); return p
ports = {}
for i, ver in enumerate(('old', 'new')):
    b = dirs[ver]
    sock = f'{tmp}/{ver}.sock'
    spawn(['redis-server', '--port', '0', '--unixsocket', sock, '--save', '', '--appendonly', 'no', '--dir', tmp], f'{tmp}/redis-{ver}.log')
    time.sleep(0.3)
    pa, pb = 18100 + 2 * i, 18101 + 2 * i
    spawn([b + '/tally-server', '--listen', f'127.0.0.1:{pa}', '--data-dir', f'{tmp}/{ver}-a', '--workers', '2', '--checkpoint-interval', '0.5'], f'{tmp}/{ver}-a.log')
    spawn([b + '/tally-server', '--listen', f'127.0.0.1:{pb}', '--data-dir', f'{tmp}/{ver}-b', '--checkpoint-interval', '0.5', '--redis', 'unix://' + sock], f'{tmp}/{ver}-b.log')
    spawn([b + '/tally-worker', '--redis', 'unix://' + sock, '--threads', '2', '--name', 'w' + ver], f'{tmp}/{ver}-w.log')
    ports[ver + '-A'] = pa; ports[ver + '-B'] = pb
time.sleep(2)
if which == 'image':
    spec = json.load(open(os.path.join(os.path.dirname(os.path.abspath(__file__)), '../../examples/lecture_lighting_image.json')))
    spec['stop'] = {'max_samples': 256}; spec['query'].pop('adaptive', None)
else:
    spec = {"kind": "integrate", "integrand": {"builtin": "unit_disk"}, "domain": {"type": "box", "lower": [-1, -1], "upper": [1, 1]}, "seed": 1, "stop": {"max_samples": 400000000}}
def req(port, method, path, body=None):
    r = urllib.request.Request(f'http://127.0.0.1:{port}{path}', method=method, data=json.dumps(body).encode() if body else None, headers={'Content-Type': 'application/json'})
    with urllib.request.urlopen(r) as f: return json.loads(f.read())
def job(port):
    j = req(port, 'POST', '/v1/jobs', spec)
    while True:
        s = req(port, 'GET', '/v1/jobs/' + j['id'])
        if s['state'] not in ('queued', 'running'): break
        time.sleep(0.02)
    if s['state'] != 'succeeded': print('FAILED', port, s.get('error_message')); sys.exit(1)
    return s['timing']['wall_seconds'], s.get('bits')
keys = list(ports)
for k in keys: job(ports[k])
res = {k: [] for k in keys}
bits = set()
for r in range(rounds):
    order = keys[r % 4:] + keys[:r % 4]
    if r % 2: order = order[::-1]
    for k in order:
        w, b = job(ports[k]); res[k].append(w); bits.add(json.dumps(b))
        time.sleep(float(os.environ.get("PAUSE", "0.6")))
for ver in ('old', 'new'):
    ratios = [b / a for a, b in zip(res[ver + '-A'], res[ver + '-B'])]
    q = statistics.quantiles(ratios, n=4)
    print(f'{which} {ver}: in-process {statistics.median(res[ver+"-A"]):.3f} s  cluster {statistics.median(res[ver+"-B"]):.3f} s  ratio median {statistics.median(ratios):.3f} [q1 {q[0]:.3f}, q3 {q[2]:.3f}]')
print('new/old in-process', round(statistics.median(res['new-A']) / statistics.median(res['old-A']), 3), 'new/old cluster', round(statistics.median(res['new-B']) / statistics.median(res['old-B']), 3), 'distinct bits', len(bits))
