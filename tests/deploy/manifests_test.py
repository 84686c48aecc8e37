#!/usr/bin/python3
"""Offline checks of the deployment files (no kubectl, docker or hadolint here):
every Kubernetes YAML document parses and has what its kind needs, the
kustomizations list files that exist, probes are native gRPC probes on the
serving port, HTTP is served and exposed where it is listened on, the Dockerfile
is multi-stage with a non-root user, a health check and the viewer's files and
three.js, and the nginx configuration routes by the mesh header (gRPC) and
the mesh in the URL (HTTP). The nginx Deployment runs nginx through
geodesicd-upstreams.sh on the files of deploy/nginx, with somewhere to write
the server lists geodesicd.conf includes, and tries every StatefulSet pod.

Usage: manifests_test.py SOURCE_DIR
"""
import glob
import os
import re
import sys

import yaml

SRC = sys.argv[1]
DEPLOY = os.path.join(SRC, "deploy")
errors = []


def need(cond, message):
    if not cond:
        errors.append(message)


def check_pod_spec(where, spec, serving_port=None):
    need(spec.get("containers"), f"{where}: no containers")
    for c in spec.get("containers", []):
        name = f"{where}/{c.get('name')}"
        need(c.get("image"), f"{name}: no image")
        need(c.get("resources", {}).get("limits", {}).get("memory"), f"{name}: no memory limit")
        if serving_port:
            ports = {p["name"]: p["containerPort"] for p in c.get("ports", [])}
            need(ports.get("grpc") == serving_port, f"{name}: grpc port is not {serving_port}")
            for probe in ("livenessProbe", "readinessProbe"):
                grpc = c.get(probe, {}).get("grpc", {})
                need(grpc.get("port") == serving_port, f"{name}: {probe} is not a gRPC probe on "
                                                       f"port {serving_port}")
            args = " ".join(c.get("args", []))
            m = re.search(r"--listen=\S+:(\d+)", args)
            need(m and int(m.group(1)) == serving_port, f"{name}: --listen is not the probed port")
            m = re.search(r"--http-listen=\S+:(\d+)", args)
            need(m and ports.get("http") == int(m.group(1)),
                 f"{name}: no container port named http for --http-listen")
    sc = spec.get("securityContext", {})
    need(sc.get("runAsNonRoot") is True, f"{where}: pods must run as non-root")


def check_document(path, doc):
    kind = doc.get("kind")
    where = f"{os.path.relpath(path, SRC)}:{kind}/{doc.get('metadata', {}).get('name')}"
    need(doc.get("apiVersion"), f"{where}: no apiVersion")
    need(kind, f"{where}: no kind")
    if kind == "Kustomization":
        base = os.path.dirname(path)
        for r in doc.get("resources", []):
            need(os.path.exists(os.path.join(base, r)), f"{where}: lists missing file {r}")
        # `kubectl apply -k` of the base silently leaves out a file it does
        # not list (the build Job's merge is applied by hand, on purpose).
        if os.path.basename(base) == "base":
            for f in sorted(glob.glob(os.path.join(base, "*.yaml"))):
                name = os.path.basename(f)
                need(name == "kustomization.yaml" or name in doc.get("resources", []),
                     f"{where}: does not list {name}")
        return
    need(doc.get("metadata", {}).get("name"), f"{where}: no metadata.name")
    spec = doc.get("spec", {})
    if kind == "StatefulSet":
        check_pod_spec(where, spec["template"]["spec"], serving_port=50051)
        labels = spec["template"]["metadata"]["labels"]
        for k, v in spec["selector"]["matchLabels"].items():
            need(labels.get(k) == v, f"{where}: selector {k}={v} does not match the pod labels")
        need(spec.get("serviceName"), f"{where}: no serviceName")
        # --mesh-root must be a volume someone can fill: an emptyDir mounted
        # read-only is always empty, so registering by path could never work.
        pod = spec["template"]["spec"]
        volumes = {v["name"]: v for v in pod.get("volumes", [])}
        for c in pod.get("containers", []):
            args = " ".join(c.get("args", []))
            root = re.search(r"--mesh-root=(\S+)", args)
            if not root:
                continue
            mounts = [m for m in c.get("volumeMounts", []) if m["mountPath"] == root.group(1)]
            need(mounts, f"{where}: no volume mounted at --mesh-root {root.group(1)}")
            for m in mounts:
                need("persistentVolumeClaim" in volumes.get(m["name"], {}),
                     f"{where}: --mesh-root volume {m['name']} is not a PersistentVolumeClaim")
    elif kind == "Deployment":
        check_pod_spec(where, spec["template"]["spec"])
        labels = spec["template"]["metadata"]["labels"]
        for k, v in spec["selector"]["matchLabels"].items():
            need(labels.get(k) == v, f"{where}: selector {k}={v} does not match the pod labels")
    elif kind == "Job":
        check_pod_spec(where, spec["template"]["spec"])
        if spec.get("completionMode") == "Indexed":
            args = " ".join(spec["template"]["spec"]["containers"][0].get("args", []))
            need("JOB_COMPLETION_INDEX" in args and "--part" in args,
                 f"{where}: an Indexed Job must pass its index to --part")
    elif kind == "Service":
        need(spec.get("ports"), f"{where}: no ports")
        targets = {p.get("targetPort") for p in spec.get("ports", [])}
        need({"grpc", "http"} <= targets, f"{where}: does not expose both grpc and http")
    elif kind == "PodDisruptionBudget":
        need("maxUnavailable" in spec or "minAvailable" in spec, f"{where}: no budget")
    elif kind not in ("ConfigMap", "PersistentVolumeClaim"):
        errors.append(f"{where}: unexpected kind")


def check_nginx_deployment(docs):
    """The nginx pods run deploy/nginx's files through geodesicd-upstreams.sh."""
    where = "deploy/k8s/base nginx"
    conf = open(os.path.join(DEPLOY, "nginx", "geodesicd.conf")).read()
    script = open(os.path.join(DEPLOY, "nginx", "geodesicd-upstreams.sh")).read()
    def runs_script(c):
        return "geodesicd-upstreams.sh" in " ".join(c.get("command", []) + c.get("args", []))

    deployments = [d for d in docs if d.get("kind") == "Deployment"
                   and any(runs_script(c) for c in d["spec"]["template"]["spec"]["containers"])]
    need(len(deployments) == 1, f"{where}: no Deployment runs nginx through geodesicd-upstreams.sh")
    if not deployments:
        return
    pod = deployments[0]["spec"]["template"]["spec"]
    c = next(c for c in pod["containers"] if runs_script(c))
    argv = c.get("command", []) + c.get("args", [])
    volumes = {v["name"]: v for v in pod.get("volumes", [])}
    mounts = {m["mountPath"]: volumes.get(m["name"], {}) for m in c.get("volumeMounts", [])}
    maps = {d["metadata"]["name"]: d.get("data", {}) for d in docs if d.get("kind") == "ConfigMap"}

    def mounted(path):  # the ConfigMap data a file path in the container reads, or None
        d, name = os.path.split(path)
        cm = mounts.get(d, {}).get("configMap")
        return maps.get(cm["name"], {}).get(name) if cm else None

    script_path = next((a for a in argv if a.endswith("geodesicd-upstreams.sh")), "")
    need(mounted(script_path) == script,
         f"{where}: {script_path} is not deploy/nginx/geodesicd-upstreams.sh "
         "(copy it into nginx-configmap.yaml, indented under its key)")
    need("run" in argv, f"{where}: the script does not run nginx")
    main_conf = argv[argv.index("-c") + 1] if "-c" in argv[:-1] else ""
    main = mounted(main_conf) or ""
    need(main, f"{where}: nginx's -c {main_conf!r} is not a ConfigMap file")
    included = re.findall(r"^\s*include\s+(\S+);", main, re.M)
    need(any(mounted(p) == conf for p in included),
         f"{where}: nginx.conf includes no copy of deploy/nginx/geodesicd.conf "
         "(copy it into nginx-configmap.yaml, indented under its key)")
    need(not re.search(r"^\s*daemon\s", main, re.M),
         f"{where}: nginx.conf sets daemon, which the script sets to off")
    # Where the script writes the server lists is where geodesicd.conf reads them.
    env = {e["name"]: e.get("value") for e in c.get("env", [])}
    default_dir = re.search(r"dir=\$\{GEODESICD_UPSTREAMS_DIR:-(\S+?)\}", script)
    lists_dir = env.get("GEODESICD_UPSTREAMS_DIR") or (default_dir.group(1) if default_dir else "")
    for f in ("grpc-servers.conf", "http-servers.conf"):
        need(f"include {lists_dir}/{f};" in conf,
             f"{where}: geodesicd.conf does not include {lists_dir}/{f}")
    need("emptyDir" in mounts.get(lists_dir, {}), f"{where}: no writable volume at {lists_dir}")
    # Pods the script does not try never get traffic.
    sets = [d for d in docs if d.get("kind") == "StatefulSet"]
    for st in sets:
        n = int(env.get("GEODESICD_REPLICAS") or 3)
        need(n >= st["spec"].get("replicas", 1),
             f"{where}: GEODESICD_REPLICAS={n} leaves out some of the "
             f"{st['spec']['replicas']} pods")
        name = env.get("GEODESICD_REPLICA_NAME") or "geodesicd-%d.geodesicd-headless"
        need(name == f"{st['metadata']['name']}-%d.{st['spec']['serviceName']}",
             f"{where}: GEODESICD_REPLICA_NAME {name} does not name the StatefulSet's pods")
    ports = {p["name"]: p["containerPort"] for p in c.get("ports", [])}
    need(f"listen {ports.get('grpc')} http2;" in conf and f"listen {ports.get('http')};" in conf,
         f"{where}: the container's grpc and http ports are not the ones geodesicd.conf listens on")


def main():
    paths = sorted(glob.glob(os.path.join(DEPLOY, "k8s", "**", "*.yaml"), recursive=True))
    need(paths, "no Kubernetes manifests under deploy/k8s")
    kinds = set()
    base_docs = []
    for path in paths:
        try:
            docs = [d for d in yaml.safe_load_all(open(path)) if d]
        except yaml.YAMLError as e:
            errors.append(f"{path}: does not parse: {e}")
            continue
        for doc in docs:
            kinds.add(doc.get("kind"))
            check_document(path, doc)
        if os.path.basename(os.path.dirname(path)) == "base":
            base_docs += docs
    for kind in ("StatefulSet", "Service", "PodDisruptionBudget", "ConfigMap", "Job", "Deployment"):
        need(kind in kinds, f"no {kind} in deploy/k8s")
    check_nginx_deployment(base_docs)

    docker = open(os.path.join(DEPLOY, "Dockerfile")).read()
    stages = re.findall(r"^FROM\s+(\S+)\s+AS\s+(\S+)", docker, re.M | re.I)
    need(len(stages) >= 2, "Dockerfile: expected a multi-stage build")
    need(all(image.startswith("debian:12") for image, _ in stages), "Dockerfile: stages must be Debian 12")
    users = re.findall(r"^USER\s+(\S+)", docker, re.M)
    need(users and users[-1] not in ("root", "0"), "Dockerfile: the runtime must not run as root")
    need(re.search(r"^HEALTHCHECK\s", docker, re.M), "Dockerfile: no HEALTHCHECK")
    need(re.search(r"^VOLUME\s.*graphs", docker, re.M), "Dockerfile: the graph directory is not a volume")
    need(not re.search(r"apt-get install(?!.*--no-install-recommends)", docker),
         "Dockerfile: apt-get install without --no-install-recommends")
    # The viewer needs its files (the installed layout) and Debian's three.js.
    http = re.search(r'"--http-listen",\s*"\S+:(\d+)"', docker)
    need(http, "Dockerfile: the entrypoint does not serve HTTP (--http-listen)")
    if http:
        exposed = re.search(r"^EXPOSE\s+(.*)$", docker, re.M)
        need(exposed and http.group(1) in exposed.group(1).split(),
             f"Dockerfile: HTTP port {http.group(1)} is not exposed")
    runtime = docker[docker.rfind("\nFROM"):]
    need("libjs-three" in runtime, "Dockerfile: the runtime stage lacks libjs-three")
    need(re.search(r"cmake --install build --prefix (\S+)", docker) and
         re.search(r"^COPY --from=build /opt/geodesicd/? /usr/local/?$", runtime, re.M),
         "Dockerfile: the runtime does not copy the installed layout into /usr/local")

    nginx = open(os.path.join(DEPLOY, "nginx", "geodesicd.conf")).read()
    need("hash $http_x_geodesic_mesh consistent" in nginx, "nginx: not hashing the mesh header")
    need("grpc_pass" in nginx and "http2" in nginx, "nginx: not proxying gRPC over HTTP/2")
    need("hash $geodesic_url_mesh consistent" in nginx and "proxy_pass http://geodesicd_http" in nginx
         and "listen 8080;" in nginx, "nginx: not routing HTTP by the mesh in the URL")

    unit = open(os.path.join(DEPLOY, "systemd", "geodesicd.service")).read()
    for key in ("ExecStart=", "DynamicUser=yes", "ProtectSystem=strict", "StateDirectory="):
        need(key in unit, f"systemd unit: missing {key}")

    for e in errors:
        print("FAIL", e)
    print(f"checked {len(paths)} manifest files, Dockerfile, nginx and systemd: "
          f"{len(errors)} problems")
    return 1 if errors else 0


if __name__ == "__main__":
    sys.exit(main())
