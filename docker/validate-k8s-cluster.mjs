// Schema-checks the rendered cluster overlay (docker/k8s-cluster, multi-document YAML on
// stdin) with kubernetes-models, then checks the cluster-mode policy of docs/cluster.md:
// the server runs with --redis, a worker Deployment with replicas, resources and a
// liveness probe, Redis as a StatefulSet + Service, and a NetworkPolicy that admits only
// tally pods (server and workers) to Redis. Run by docker/validate-manifests.sh.
import { createRequire } from "node:module";
import { readFileSync } from "node:fs";
import path from "node:path";
import { pathToFileURL } from "node:url";

const modulesDir = process.env.TALLY_NODE_MODULES;
if (!modulesDir) {
  console.error("validate-k8s-cluster: set TALLY_NODE_MODULES to the node_modules folder");
  process.exit(2);
}
const require = createRequire(path.join(modulesDir, "..", "package.json"));
const YAML = require("yaml");
const docs = YAML.parseAllDocuments(readFileSync(0, "utf8")).map((d) => {
  if (d.errors.length) throw new Error(`YAML: ${d.errors[0].message}`);
  return d.toJS();
}).filter((d) => d);

let failures = 0;
const expect = (where, cond, msg) => {
  if (cond) console.log(`ok   ${where}: ${msg}`);
  else {
    failures++;
    console.log(`FAIL ${where}: ${msg}`);
  }
};

for (const doc of docs) {
  const where = `${doc.kind}/${doc.metadata?.name}`;
  const [group, version] = doc.apiVersion.includes("/") ? doc.apiVersion.split("/") : [null, doc.apiVersion];
  const spec = path.join(modulesDir, "kubernetes-models", ...(group ? [group, version] : [version]), "index.js");
  try {
    const Model = (await import(pathToFileURL(spec).href))[doc.kind];
    if (!Model) throw new Error(`unknown kind ${doc.kind}`);
    new Model(doc).validate();
    expect(where, true, `valid ${doc.apiVersion} ${doc.kind}`);
  } catch (e) {
    expect(where, false, e.message);
  }
}

const find = (kind, name) => docs.find((d) => d.kind === kind && d.metadata?.name === name);
const server = find("Deployment", "tally-server");
const worker = find("Deployment", "tally-worker");
const redis = find("StatefulSet", "tally-redis");
const redisSvc = find("Service", "tally-redis");
const policy = docs.find((d) => d.kind === "NetworkPolicy");
const hpa = docs.find((d) => d.kind === "HorizontalPodAutoscaler");
expect("cluster", hpa, "a HorizontalPodAutoscaler for the workers");
if (hpa) {
  const where = `HorizontalPodAutoscaler/${hpa.metadata.name}`;
  expect(where, hpa.spec.scaleTargetRef?.kind === "Deployment" && hpa.spec.scaleTargetRef?.name === "tally-worker",
         "scales the tally-worker Deployment");
  const m = (hpa.spec.metrics ?? []).find((x) => x.type === "External");
  expect(where, m?.external?.metric?.name === "tally_predicted_cpu_seconds",
         "on the server's tally_predicted_cpu_seconds gauge");
  expect(where, m?.external?.target?.type === "AverageValue" && Number(m.external.target.averageValue) > 0,
         "with a per-worker target (AverageValue)");
  expect(where, hpa.spec.minReplicas >= 1 && hpa.spec.maxReplicas >= hpa.spec.minReplicas, "min 1, max >= min");
  // The Deployment's fixed replicas is only the start; the HPA owns it from then on.
}
expect("cluster", server, "the server Deployment");
expect("cluster", worker, "a tally-worker Deployment");
expect("cluster", redis && redisSvc, "Redis as a StatefulSet with a Service");
expect("cluster", policy, "a NetworkPolicy");

const args = (d) => d?.spec.template.spec.containers[0].args ?? [];
if (server) {
  const a = args(server);
  expect("Deployment/tally-server", a.includes("--redis"), "runs with --redis");
  expect("Deployment/tally-server", server.spec.replicas === 1, "still one replica (one store writer)");
}
if (worker) {
  const w = "Deployment/tally-worker";
  const pod = worker.spec.template.spec;
  const c = pod.containers[0];
  expect(w, worker.spec.replicas >= 1, `replicas: ${worker.spec.replicas}`);
  expect(w, (c.command ?? []).join(" ").includes("tally-worker"), "runs tally-worker");
  expect(w, args(worker).includes("--redis") && args(worker).includes("--health-file"), "--redis and --health-file");
  const r = c.resources ?? {};
  expect(w, r.requests?.cpu && r.requests?.memory && r.limits?.cpu && r.limits?.memory, "cpu/memory requests and limits");
  const threads = Number(args(worker)[args(worker).indexOf("--threads") + 1]);
  expect(w, threads >= 1 && String(threads) === String(r.limits?.cpu), "--threads equals the CPU limit");
  expect(w, c.livenessProbe?.exec?.command?.join(" ").includes("/tmp/alive"), "liveness probe on the heartbeat file");
  const sc = c.securityContext ?? {};
  expect(w, sc.runAsNonRoot === true && sc.readOnlyRootFilesystem === true && sc.allowPrivilegeEscalation === false,
    "non-root, read-only root, no privilege escalation");
  expect(w, (c.volumeMounts ?? []).some((m) => m.mountPath === "/tmp"), "writable /tmp (asset cache, heartbeat file)");
  expect(w, pod.securityContext?.seccompProfile?.type === "RuntimeDefault", "seccompProfile RuntimeDefault");
}
if (redis) {
  const a = args(redis).join(" ");
  expect("StatefulSet/tally-redis", a.includes("--maxmemory-policy noeviction"), "maxmemory-policy noeviction");
  expect("StatefulSet/tally-redis", a.includes("--appendonly no") && a.includes('--save '), "no persistence");
}
if (redisSvc && redis) {
  const labels = redis.spec.template.metadata.labels;
  const sel = redisSvc.spec.selector ?? {};
  expect("Service/tally-redis", Object.entries(sel).every(([k, v]) => labels[k] === v), "selector matches Redis pods");
  expect("Service/tally-redis", redisSvc.spec.type === undefined || redisSvc.spec.type === "ClusterIP",
    "ClusterIP only (not exposed outside the cluster)");
}
if (policy && redis && server && worker) {
  const p = "NetworkPolicy";
  const sel = policy.spec.podSelector.matchLabels ?? {};
  const rl = redis.spec.template.metadata.labels;
  expect(p, Object.entries(sel).every(([k, v]) => rl[k] === v), "selects the Redis pods");
  expect(p, (policy.spec.policyTypes ?? []).includes("Ingress"), "restricts ingress");
  const from = (policy.spec.ingress ?? []).flatMap((i) => i.from ?? []);
  expect(p, from.length > 0 && from.every((f) => f.podSelector && !f.namespaceSelector && !f.ipBlock),
    "admits pods of this namespace only, by label");
  const admits = (d) => from.some((f) =>
    Object.entries(f.podSelector.matchLabels ?? {}).every(([k, v]) => d.spec.template.metadata.labels?.[k] === v));
  expect(p, admits(server), "admits the server");
  expect(p, admits(worker), "admits the workers");
}
console.log(`k8s cluster: ${docs.length} objects, ${failures} failed checks`);
process.exit(failures ? 1 : 0);
