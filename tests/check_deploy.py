#!/usr/bin/env python3
"""Checks deploy/: the Kubernetes manifests and compose file parse and hold what an operator
relies on (probes, resource requests, the autoscaler, the map volume), the processes they start
use the arguments deploy/smoke.sh exercises, and the systemd unit has its hardening.
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
for kind in ("Deployment", "Service", "HorizontalPodAutoscaler", "PersistentVolumeClaim"):
    check(kind in kinds, f"kubernetes: no {kind}")

smoke = (deploy / "smoke.sh").read_text()
arguments = {}
for name, document in documents:
    if document["kind"] != "Deployment":
        continue
    for container in document["spec"]["template"]["spec"]["containers"]:
        where = f"{name}: container {container['name']}"
        for probe in ("readinessProbe", "livenessProbe"):
            check(probe in container, f"{where}: no {probe}")
        check("requests" in container.get("resources", {}), f"{where}: no resource requests")
        args = container["args"]
        arguments[container["name"]] = args
        # Every flag the manifest passes is one the smoke test passes too.
        for flag in (a for a in args if a.startswith("--")):
            check(flag in smoke, f"{where}: {flag} is not exercised by smoke.sh")
check("--broker" in arguments.get("broker", []), "kubernetes: the broker does not run --broker")
check("--connect" in arguments.get("worker", []), "kubernetes: workers do not --connect")
hpa = [d for _, d in documents if d["kind"] == "HorizontalPodAutoscaler"]
check(hpa and hpa[0]["spec"]["scaleTargetRef"]["name"] == "hscloc-worker",
      "the autoscaler does not scale the workers")

compose = yaml.safe_load((deploy / "compose.yaml").read_text())
check(set(compose["services"]) >= {"broker", "worker", "batch"},
      "compose: broker, worker and batch services expected")
check(compose["services"]["worker"]["deploy"]["replicas"] == 2, "compose: two workers expected")

unit = configparser.ConfigParser(strict=False, interpolation=None)
unit.optionxform = str
unit.read(deploy / "hscloc.service")
service = unit["Service"]
check(service.get("ExecStart", "").split()[1:2] == ["serve"], "systemd: ExecStart is not serve")
for key, value in (("DynamicUser", "yes"), ("ProtectSystem", "strict"), ("NoNewPrivileges", "yes"),
                   ("Restart", "on-failure")):
    check(service.get(key) == value, f"systemd: {key}={value} expected")
check("ExecReload" in service, "systemd: no ExecReload (SIGHUP reloads the map)")

dockerfile = (deploy / "Dockerfile").read_text()
check(dockerfile.count("FROM ") >= 2, "Dockerfile: a build and a runtime stage expected")
check("debian:12" in dockerfile, "Dockerfile: Debian 12 base expected")

if errors:
    print("\n".join(errors))
    sys.exit(1)
print(f"deploy: {len(documents)} Kubernetes objects, compose, systemd unit and Dockerfile check out")
