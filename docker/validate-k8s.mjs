// Schema-checks rendered Kubernetes manifests (multi-document YAML on stdin) with
// kubernetes-models, then checks the deployment policy of docs/deployment.md: one
// replica, Recreate, probes, resources, a locked-down securityContext.
// Run by docker/validate-manifests.sh with NODE_PATH pointing at its npm folder.
import { createRequire } from "node:module";
import { readFileSync } from "node:fs";
import path from "node:path";
import { pathToFileURL } from "node:url";

const modulesDir = process.env.TALLY_NODE_MODULES;
if (!modulesDir) {
  console.error("validate-k8s: set TALLY_NODE_MODULES to the node_modules folder");
  process.exit(2);
}
const require = createRequire(path.join(modulesDir, "..", "package.json"));
const YAML = require("yaml");

const text = readFileSync(0, "utf8");
const docs = YAML.parseAllDocuments(text).map((d) => {
  if (d.errors.length) throw new Error(`YAML: ${d.errors[0].message}`);
  return d.toJS();
}).filter((d) => d);

let failures = 0;
const fail = (where, msg) => {
  failures++;
  console.log(`FAIL ${where}: ${msg}`);
};
const ok = (where, msg) => console.log(`ok   ${where}: ${msg}`);

// 1. Schema: every object against the model of its apiVersion/kind.
for (const doc of docs) {
  const where = `${doc.kind}/${doc.metadata?.name}`;
  const [group, version] = doc.apiVersion.includes("/") ? doc.apiVersion.split("/") : [null, doc.apiVersion];
  const spec = path.join(modulesDir, "kubernetes-models", ...(group ? [group, version] : [version]), "index.js");
  let mod;
  try {
    mod = await import(pathToFileURL(spec).href);
  } catch (e) {
    fail(where, `no model for ${doc.apiVersion} (${e.message})`);
    continue;
  }
  const Model = mod[doc.kind];
  if (!Model) {
    fail(where, `unknown kind ${doc.kind} in ${doc.apiVersion}`);
    continue;
  }
  try {
    new Model(doc).validate();
    ok(where, `valid ${doc.apiVersion} ${doc.kind}`);
  } catch (e) {
    fail(where, e.message);
  }
}

// 2. Policy.
const byKind = (k) => docs.filter((d) => d.kind === k);
const expect = (where, cond, msg) => (cond ? ok(where, msg) : fail(where, msg));
const deployments = byKind("Deployment");
expect("kustomization", deployments.length === 1, "exactly one Deployment");
expect("kustomization", byKind("Service").length === 1, "a Service");
expect("kustomization", byKind("PersistentVolumeClaim").length === 1, "a PersistentVolumeClaim");
for (const d of deployments) {
  const w = `Deployment/${d.metadata.name}`;
  const pod = d.spec.template.spec;
  expect(w, d.spec.replicas === 1, "replicas: 1 (SQLite has one writer)");
  expect(w, d.spec.strategy?.type === "Recreate", "strategy Recreate");
  const psc = pod.securityContext ?? {};
  expect(w, psc.seccompProfile?.type === "RuntimeDefault", "pod seccompProfile RuntimeDefault");
  expect(w, psc.runAsNonRoot === true && psc.runAsUser === 10001, "pod runs as non-root uid 10001");
  const claims = (pod.volumes ?? []).filter((v) => v.persistentVolumeClaim).map((v) => v.persistentVolumeClaim.claimName);
  for (const c of claims) {
    expect(w, byKind("PersistentVolumeClaim").some((p) => p.metadata.name === c), `claim ${c} is defined`);
  }
  for (const c of pod.containers) {
    const cw = `${w}/${c.name}`;
    const sc = c.securityContext ?? {};
    expect(cw, sc.runAsNonRoot === true, "runAsNonRoot");
    expect(cw, sc.runAsUser === 10001, "runAsUser 10001 (the image's user)");
    expect(cw, sc.readOnlyRootFilesystem === true, "readOnlyRootFilesystem");
    expect(cw, sc.allowPrivilegeEscalation === false, "allowPrivilegeEscalation false");
    expect(cw, JSON.stringify(sc.capabilities?.drop) === '["ALL"]', "capabilities drop ALL");
    expect(cw, sc.seccompProfile?.type === "RuntimeDefault", "seccompProfile RuntimeDefault");
    expect(cw, c.startupProbe?.httpGet?.path === "/readyz", "startupProbe on /readyz");
    expect(cw, c.readinessProbe?.httpGet?.path === "/readyz", "readinessProbe on /readyz");
    expect(cw, c.livenessProbe?.httpGet?.path === "/livez", "livenessProbe on /livez");
    const r = c.resources ?? {};
    expect(cw, r.requests?.cpu && r.requests?.memory && r.limits?.cpu && r.limits?.memory, "cpu/memory requests and limits");
    const mounts = (c.volumeMounts ?? []).map((m) => m.mountPath);
    expect(cw, mounts.includes("/var/lib/tally"), "data volume at /var/lib/tally");
    expect(cw, mounts.includes("/tmp"), "writable /tmp (read-only root)");
    const ports = (c.ports ?? []).map((p) => p.containerPort);
    expect(cw, ports.includes(8080), "containerPort 8080");
  }
  for (const s of byKind("Service")) {
    const sel = s.spec.selector ?? {};
    const labels = d.spec.template.metadata?.labels ?? {};
    expect(`Service/${s.metadata.name}`, Object.keys(sel).length > 0 && Object.entries(sel).every(([k, v]) => labels[k] === v),
      "selector matches the pod labels");
  }
}

console.log(`k8s: ${docs.length} objects, ${failures} failed checks`);
process.exit(failures ? 1 : 0);
