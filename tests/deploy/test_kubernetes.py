"""deploy/kubernetes: every manifest validates (strict) against a pinned Kubernetes version, and what the manifests
assume of the image and the service holds: port, user, probes' route, settings' names, selectors."""
from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml

from t2m.service.settings import Settings

kubernetes_validate = pytest.importorskip("kubernetes_validate", reason="needs the dev extra (kubernetes-validate)")

REPO = Path(__file__).resolve().parents[2]
MANIFESTS = REPO / "deploy" / "kubernetes"
KUBERNETES_VERSION = "1.31.0"
DOCKERFILE = (REPO / "Dockerfile").read_text()


def documents(name: str) -> list[dict]:
    return [doc for doc in yaml.safe_load_all((MANIFESTS / name).read_text()) if doc]


def resource_files() -> list[str]:
    return sorted(p.name for p in MANIFESTS.glob("*.yaml") if p.name != "kustomization.yaml")


def deployment() -> dict:
    (doc,) = documents("deployment.yaml")
    return doc


def container() -> dict:
    (only,) = deployment()["spec"]["template"]["spec"]["containers"]
    return only


@pytest.mark.parametrize("name", resource_files())
def test_manifest_validates_strictly(name):
    for doc in documents(name):
        kubernetes_validate.validate(doc, KUBERNETES_VERSION, strict=True)


def test_a_broken_manifest_is_refused():
    """The validation above can fail: a misspelt field is an error in strict mode."""
    doc = deployment()
    doc["spec"]["template"]["spec"]["containers"][0]["readinesProbe"] = {"httpGet": {"path": "/health"}}
    with pytest.raises(kubernetes_validate.ValidationError):
        kubernetes_validate.validate(doc, KUBERNETES_VERSION, strict=True)


def test_kustomization_lists_every_resource_but_the_alternative_hpa():
    listed = set(documents("kustomization.yaml")[0]["resources"])
    assert listed == set(resource_files()) - {"hpa-queue-depth.yaml"}


def test_port_and_user_are_the_images():
    exposed = re.search(r"^EXPOSE (\d+)", DOCKERFILE, re.MULTILINE)
    uid = re.search(r"useradd .*--uid (\d+)", DOCKERFILE)
    assert exposed and uid
    (port,) = container()["ports"]
    assert port["containerPort"] == int(exposed.group(1))
    pod_security = deployment()["spec"]["template"]["spec"]["securityContext"]
    assert pod_security["runAsNonRoot"] is True and pod_security["runAsUser"] == int(uid.group(1))


def test_probes_use_the_health_route_on_the_named_port():
    c = container()
    for probe in ("startupProbe", "readinessProbe", "livenessProbe"):
        assert c[probe]["httpGet"] == {"path": "/health", "port": c["ports"][0]["name"]}


def test_read_only_root_with_a_writable_tmp_and_resources_set():
    c = container()
    assert c["securityContext"]["readOnlyRootFilesystem"] is True
    assert c["securityContext"]["capabilities"]["drop"] == ["ALL"]
    assert {"name": "tmp", "mountPath": "/tmp"} in c["volumeMounts"]
    assert set(c["resources"]) == {"requests", "limits"}
    assert {"cpu", "memory"} <= set(c["resources"]["requests"]) and {"cpu", "memory"} <= set(c["resources"]["limits"])


def test_every_environment_variable_is_a_setting_of_the_service():
    fields = {f"T2M_{name.upper()}" for name in Settings.model_fields}
    names = {env["name"] for env in container()["env"]}
    assert names <= fields, names - fields


def test_grace_period_outlasts_the_request_timeout():
    env = {e["name"]: e.get("value") for e in container()["env"]}
    grace = deployment()["spec"]["template"]["spec"]["terminationGracePeriodSeconds"]
    assert grace > float(env["T2M_REQUEST_TIMEOUT_S"]) + 5  # + the preStop sleep


def test_service_hpa_and_pdb_point_at_the_deployment():
    labels = deployment()["spec"]["template"]["metadata"]["labels"]
    name = deployment()["metadata"]["name"]
    (service,) = documents("service.yaml")
    assert service["spec"]["selector"].items() <= labels.items()
    assert service["spec"]["ports"][0]["targetPort"] == container()["ports"][0]["name"]
    for hpa_file in ("hpa.yaml", "hpa-queue-depth.yaml"):
        (hpa,) = documents(hpa_file)
        assert hpa["spec"]["scaleTargetRef"] == {"apiVersion": "apps/v1", "kind": "Deployment", "name": name}
    (pdb,) = documents("pdb.yaml")
    assert pdb["spec"]["selector"]["matchLabels"].items() <= labels.items()


def test_the_queue_metric_the_alternative_hpa_scales_on_exists():
    from prometheus_client import generate_latest

    from t2m.service.metrics import ServiceMetrics

    (hpa,) = documents("hpa-queue-depth.yaml")
    metric = hpa["spec"]["metrics"][0]["pods"]["metric"]["name"]
    metrics = ServiceMetrics()
    metrics.add_model("m", "1", queue_depth=lambda: 3.0, in_flight=lambda: 0.0)
    assert f'{metric}{{model="m"}} 3.0' in generate_latest(metrics.registry).decode()


def gpu_deployment() -> dict:
    (doc,) = [doc for doc in yaml.safe_load_all((MANIFESTS / "gpu" / "deployment.yaml").read_text()) if doc]
    return doc


def test_gpu_variant_validates_and_asks_for_one_gpu_with_cuda():
    doc = gpu_deployment()
    kubernetes_validate.validate(doc, KUBERNETES_VERSION, strict=True)
    (c,) = doc["spec"]["template"]["spec"]["containers"]
    assert c["resources"]["limits"]["nvidia.com/gpu"] == c["resources"]["requests"]["nvidia.com/gpu"] == 1
    env = {e["name"]: e.get("value") for e in c["env"]}
    assert env["T2M_EXECUTION_PROVIDERS"] == "cuda" and Settings(execution_providers="cuda").execution.binds
    fields = {f"T2M_{name.upper()}" for name in Settings.model_fields}
    assert set(env) <= fields, set(env) - fields
    (listed,) = [doc for doc in yaml.safe_load_all((MANIFESTS / "gpu" / "kustomization.yaml").read_text()) if doc]
    assert listed["resources"] == ["deployment.yaml"]


def test_gpu_variant_differs_from_the_cpu_deployment_only_where_it_says():
    """Probes, security, ports, volumes and the rest stay the CPU deployment's (no drift between the two)."""
    cpu, gpu = deployment(), gpu_deployment()
    cpu_pod, gpu_pod = cpu["spec"]["template"]["spec"], gpu["spec"]["template"]["spec"]
    (cpu_c,), (gpu_c,) = cpu_pod.pop("containers"), gpu_pod.pop("containers")
    assert gpu_pod.pop("tolerations") == [{"key": "nvidia.com/gpu", "operator": "Exists", "effect": "NoSchedule"}]
    assert gpu_pod == cpu_pod
    assert gpu_c["image"] == cpu_c["image"] + "-gpu"
    for key in ("image", "env", "resources", "startupProbe"):
        cpu_c.pop(key), gpu_c.pop(key)
    assert gpu_c == cpu_c
    assert {k: v for k, v in gpu["spec"].items() if k not in ("replicas", "template")} == \
        {k: v for k, v in cpu["spec"].items() if k not in ("replicas", "template")}
