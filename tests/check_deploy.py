#!/usr/bin/env python3
"""Checks deploy/: the Kubernetes manifests and compose file parse and hold what an operator
relies on (probes, resource requests, the autoscaler, the map volume), no single point of failure
(two broker replicas on different nodes, a disruption budget, every worker registered with every
broker and the clients given every broker), every process they start
runs with CURVE (keys from a Secret) and is probed on its own admin endpoint, never through a
Service, exposes its metrics where Prometheus scrapes them, the autoscaler scales on the broker's
queue beside CPU, the processes use the arguments deploy/smoke.sh exercises, and the systemd unit
has its hardening and uses its admin endpoint.
Usage: check_deploy.py DEPLOY_DIR"""
import configparser
import pathlib
import sys

import yaml

deploy = pathlib.Path(sys.argv[1])
errors = []


def check(condition, message):
    if not condition:
        errors.append(message)


documents = []
for path in sorted((deploy / "kubernetes").glob("*.yaml")):
    for document in yaml.safe_load_all(path.read_text()):
        if document:
            documents.append((path.name, document))
kinds = {document["kind"] for _, document in documents}
for kind in ("Deployment", "StatefulSet", "Service", "HorizontalPodAutoscaler",
             "PersistentVolumeClaim", "PodDisruptionBudget"):
    check(kind in kinds, f"kubernetes: no {kind}")

# The CURVE flags each role must run with.
CURVE_FLAGS = {
    "broker": ["--curve-secret-key", "--curve-allowed-keys", "--backend-curve-secret-key",
               "--curve-allowed-worker-keys"],
    "worker": ["--curve-secret-key", "--curve-server-key"],
}
LOCAL_HOSTS = ("tcp://127.0.0.1:", "tcp://localhost:", "ipc://")


def flag_value(args, flag):
    return args[args.index(flag) + 1] if flag in args and args.index(flag) + 1 < len(args) else None


def check_local_probe(where, command, args, live, services):
    """A probe runs hscloc-client health on the process's own admin endpoint."""
    check(command[:1] == ["hscloc-client"] and "health" in command,
          f"{where}: the probe is not hscloc-client health")
    server = flag_value(command, "--server") or ""
    check(server.startswith(LOCAL_HOSTS), f"{where}: the probe asks {server!r}, not this process")
    check(server == flag_value(args, "--admin-bind"),
          f"{where}: the probe asks {server!r}, the process's admin endpoint is "
          f"{flag_value(args, '--admin-bind')!r}")
    host = server.split("://")[-1].rsplit(":", 1)[0]
    check(host not in services, f"{where}: the probe goes through the Service {host}")
    check(("--live" in command) == live,
          f"{where}: {'liveness' if live else 'readiness'} probe {'without' if live else 'with'} --live")


def check_curve(where, role, args, key_dirs):
    for flag in CURVE_FLAGS.get(role, []):
        value = flag_value(args, flag)
        check(value is not None, f"{where}: runs without {flag}")
        if value is not None:
            check(any(value.startswith(d + "/") for d in key_dirs),
                  f"{where}: {flag} {value} is not on a volume of keys from a Secret")


def check_metrics(where, args, ports, annotations):
    """The process serves its metrics on every interface, on a port the pod opens and names in its
    scrape annotations."""
    bind = flag_value(args, "--metrics-bind") or ""
    host, _, port = bind.rpartition(":")
    check(host == "0.0.0.0" and port.isdigit(),
          f"{where}: --metrics-bind {bind!r} is not reachable by Prometheus")
    if ports is not None:
        check(port.isdigit() and int(port) in ports, f"{where}: the metrics port is not opened")
    if annotations is not None:
        check(annotations.get("prometheus.io/scrape") == "true" and
              annotations.get("prometheus.io/port") == port,
              f"{where}: the pod's annotations do not point Prometheus at port {port}")


services = [d["metadata"]["name"] for _, d in documents if d["kind"] == "Service"]
smoke = (deploy / "smoke.sh").read_text()
arguments = {}
for name, document in documents:
    if document["kind"] not in ("Deployment", "StatefulSet"):
        continue
    pod = document["spec"]["template"]["spec"]
    secret_volumes = {v["name"] for v in pod.get("volumes", []) if "secret" in v}
    for container in pod["containers"]:
        where = f"{name}: container {container['name']}"
        args = container["args"]
        for probe, live in (("readinessProbe", False), ("livenessProbe", True)):
            check(probe in container, f"{where}: no {probe}")
            spec = container.get(probe, {})
            check("exec" in spec, f"{where}: {probe} does not ask the process itself (exec)")
            if "exec" in spec:
                check_local_probe(f"{where} {probe}", spec["exec"]["command"], args, live, services)
        check("requests" in container.get("resources", {}), f"{where}: no resource requests")
        key_dirs = [m["mountPath"] for m in container.get("volumeMounts", [])
                    if m["name"] in secret_volumes]
        check_curve(where, container["name"], args, key_dirs)
        check_metrics(where, args, [p["containerPort"] for p in container.get("ports", [])],
                      document["spec"]["template"]["metadata"].get("annotations", {}))
        arguments[container["name"]] = args
        # Every flag the manifest passes is one the smoke test passes too.
        for flag in (a for a in args if a.startswith("--")):
            check(flag in smoke, f"{where}: {flag} is not exercised by smoke.sh")
check("--broker" in arguments.get("broker", []), "kubernetes: the broker does not run --broker")
check("--connect" in arguments.get("worker", []), "kubernetes: workers do not --connect")


def connected(args):
    return [args[i + 1] for i, a in enumerate(args[:-1]) if a == "--connect"]


# No single point of failure: two brokers, each with its own name, never on one node, never both
# disrupted at once, and every worker registered with each of them.
brokers = [d for _, d in documents if d["kind"] == "StatefulSet" and
           d["spec"]["selector"]["matchLabels"].get("role") == "broker"]
check(len(brokers) == 1, "kubernetes: the brokers are not one StatefulSet")
if brokers:
    spec = brokers[0]["spec"]
    replicas = spec.get("replicas", 1)
    check(replicas >= 2, f"kubernetes: {replicas} broker replica(s); one is a single point of failure")
    headless = [d for _, d in documents if d["kind"] == "Service" and
                d["metadata"]["name"] == spec.get("serviceName")]
    check(headless and headless[0]["spec"].get("clusterIP") == "None",
          "kubernetes: the brokers' Service is not headless (one name per broker)")
    anti = spec["template"]["spec"].get("affinity", {}).get("podAntiAffinity", {})
    terms = anti.get("requiredDuringSchedulingIgnoredDuringExecution", [])
    check(any(t.get("topologyKey") == "kubernetes.io/hostname" and
              t["labelSelector"]["matchLabels"] == spec["selector"]["matchLabels"] for t in terms),
          "kubernetes: two brokers may land on one node (no required anti-affinity)")
    budgets = [d for _, d in documents if d["kind"] == "PodDisruptionBudget" and
               d["spec"]["selector"]["matchLabels"] == spec["selector"]["matchLabels"]]
    check(budgets and budgets[0]["spec"].get("minAvailable") == 1,
          "kubernetes: no disruption budget keeps a broker up")
    expected = {f"tcp://{brokers[0]['metadata']['name']}-{n}.{spec.get('serviceName')}:5556"
                for n in range(replicas)}
    check(set(connected(arguments.get("worker", []))) == expected,
          f"kubernetes: workers connect to {connected(arguments.get('worker', []))}, "
          f"not to every broker {sorted(expected)}")
hpa = [d for _, d in documents if d["kind"] == "HorizontalPodAutoscaler"]
check(hpa and hpa[0]["spec"]["scaleTargetRef"]["name"] == "hscloc-worker",
      "the autoscaler does not scale the workers")
scaled_on = {m.get("resource", m.get("external", {}).get("metric", {})).get("name")
             for m in (hpa[0]["spec"].get("metrics", []) if hpa else [])}
check({"cpu", "hscloc_broker_queue_depth"} <= scaled_on,
      f"the autoscaler scales on {sorted(map(str, scaled_on))}, not on CPU and the broker's queue")

compose = yaml.safe_load((deploy / "compose.yaml").read_text())
check(set(compose["services"]) >= {"broker", "worker", "batch"},
      "compose: broker, worker and batch services expected")
check(compose["services"]["worker"]["deploy"]["replicas"] == 2, "compose: two workers expected")
for role in ("broker", "worker"):
    service = compose["services"][role]
    check_curve(f"compose {role}", role, service["command"], ["/run/secrets"])
    check_metrics(f"compose {role}", service["command"], None, None)
    healthcheck = service.get("healthcheck", {}).get("test", [])[1:]
    check(bool(healthcheck), f"compose {role}: no healthcheck")
    if healthcheck:
        check_local_probe(f"compose {role} healthcheck", healthcheck, service["command"], False,
                          list(compose["services"]))
    for flag in (a for a in service["command"] if a.startswith("--")):
        check(flag in smoke, f"compose {role}: {flag} is not exercised by smoke.sh")
batch = compose["services"]["batch"]["command"]
for flag in ("--curve-server-key", "--curve-secret-key"):
    check(flag in batch, f"compose batch: runs without {flag}")
compose_brokers = [name for name, service in compose["services"].items()
                   if "--broker" in service.get("command", [])]
check(len(compose_brokers) >= 2, f"compose: brokers {compose_brokers}; one is a single point of "
                                 "failure")
check(set(connected(compose["services"]["worker"]["command"])) ==
      {f"tcp://{name}:5556" for name in compose_brokers},
      "compose: the workers do not connect to every broker")
check({batch[i + 1] for i, a in enumerate(batch[:-1]) if a == "--server"} ==
      {f"tcp://{name}:5555" for name in compose_brokers},
      "compose: the batch client is not given every broker")

unit = configparser.ConfigParser(strict=False, interpolation=None)
unit.optionxform = str
unit.read(deploy / "hscloc.service")
service = unit["Service"]
check(service.get("ExecStart", "").split()[1:2] == ["serve"], "systemd: ExecStart is not serve")
for key, value in (("DynamicUser", "yes"), ("ProtectSystem", "strict"), ("NoNewPrivileges", "yes"),
                   ("Restart", "on-failure")):
    check(service.get(key) == value, f"systemd: {key}={value} expected")
exec_start = service.get("ExecStart", "").split()
admin = flag_value(exec_start, "--admin-bind") or ""
check(admin.startswith(LOCAL_HOSTS), f"systemd: the admin endpoint {admin!r} is not local")
check(f"--server {admin}" in service.get("ExecReload", "") and "reload" in service["ExecReload"],
      "systemd: ExecReload does not reload on the admin endpoint")
check(f"--server {admin}" in service.get("ExecStartPost", "") and "health" in service["ExecStartPost"],
      "systemd: ExecStartPost does not wait for readiness on the admin endpoint")

dockerfile = (deploy / "Dockerfile").read_text()
check(dockerfile.count("FROM ") >= 2, "Dockerfile: a build and a runtime stage expected")
check("debian:12" in dockerfile, "Dockerfile: Debian 12 base expected")

if errors:
    print("\n".join(errors))
    sys.exit(1)
print(f"deploy: {len(documents)} Kubernetes objects, compose, systemd unit and Dockerfile check out")
