"""The container files agree with the tested local setup (no Docker engine here): entrypoint = `t2m serve`,
health checks on /health, non-root runtime without torch, nginx in front of the replicas."""
from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys

import pytest
import yaml

from tests.service.conftest import REPO

ENTRYPOINT = ["t2m", "serve"]


def _dockerfile() -> str:
    return (REPO / "Dockerfile").read_text()


def _instruction(text: str, name: str) -> list[str]:
    """Every instruction `name` of the Dockerfile, continuation lines joined."""
    joined = re.sub(r"\\\n\s*", " ", text)
    return [line[len(name):].strip() for line in joined.splitlines() if line.startswith(name + " ")]


def test_entrypoint_is_the_local_serve_command():
    text = _dockerfile()
    (entrypoint,) = _instruction(text, "ENTRYPOINT")
    assert json.loads(entrypoint) == ENTRYPOINT
    from t2m.cli.main import build_parser

    (env,) = _instruction(text.split(" AS runtime")[1], "ENV")
    image_env = dict(re.findall(r"(T2M_\w+)=(\S+)", env))
    assert image_env == {"T2M_HOST": "0.0.0.0", "T2M_PORT": "8000"}
    with pytest.MonkeyPatch.context() as patch:  # the image's environment decides where `t2m serve` listens
        for name, value in image_env.items():
            patch.setenv(name, value)
        args = build_parser(ENTRYPOINT[1]).parse_args(ENTRYPOINT[1:])
    assert args.command == "serve" and args.host == "0.0.0.0" and args.port == 8000
    (port,) = _instruction(text, "EXPOSE")
    assert port == image_env["T2M_PORT"]
    scripts = re.search(r"\[project\.scripts\]\s*t2m = \"([\w.:]+)\"", (REPO / "pyproject.toml").read_text())
    assert scripts and scripts.group(1) == "t2m.cli.main:main"


def test_dockerfile_is_multistage_non_root_with_model_and_healthcheck():
    text = _dockerfile()
    stages = _instruction(text, "FROM")
    assert len(stages) == 2 and stages[0].endswith("AS builder") and stages[1].endswith("AS runtime")
    runtime = text.split(stages[1])[1]
    assert "torch" not in " ".join(_instruction(runtime, "RUN"))
    users = _instruction(runtime, "USER")
    assert users and users[-1] not in ("root", "0")
    (health,) = _instruction(text, "HEALTHCHECK")
    assert "'http://127.0.0.1:' + os.environ.get('T2M_PORT', '8000') + '/health'" in health  # where t2m serve listens
    assert "T2M_MODEL_DIR" not in text  # the default model is inside the installed wheel
    ignored = [line.strip() for line in (REPO / ".dockerignore").read_text().splitlines()
               if line.strip() and not line.startswith("#")]
    assert "tests" in ignored and not any(line.startswith("t2m") for line in ignored)


def _health_url(service: dict) -> str:
    test = " ".join(service["healthcheck"]["test"])
    match = re.search(r"http://127\.0\.0\.1(?::(\d+))?(/\w+)", test)
    assert match, test
    return match.group(2)


def test_compose_file():
    compose = yaml.safe_load((REPO / "docker-compose.yml").read_text())
    service = compose["services"]["t2m"]
    assert service["build"] == "."
    assert _health_url(service) == "/health"
    model_dir = service["environment"]["T2M_MODEL_DIR"]
    mounts = [volume.split(":")[1] for volume in service["volumes"]]
    assert any(model_dir.startswith(mount) for mount in mounts)
    assert service["ports"][0].endswith(":8000")
    assert "entrypoint" not in service and "command" not in service     # the image's own `t2m serve`


def test_scale_compose_and_nginx():
    compose = yaml.safe_load((REPO / "docker-compose.scale.yml").read_text())
    replicas, nginx = compose["services"]["t2m"], compose["services"]["nginx"]
    assert str(replicas["deploy"]["replicas"]).startswith("${T2M_REPLICAS") and "ports" not in replicas
    assert _health_url(replicas) == "/health"
    assert nginx["depends_on"]["t2m"]["condition"] == "service_healthy"
    source, target = nginx["volumes"][0].split(":")[:2]
    assert (REPO / source).is_file() and target == "/etc/nginx/nginx.conf"
    conf = (REPO / "deploy" / "nginx.conf").read_text()
    assert re.search(r"server t2m:8000\b", conf)
    from t2m.service.settings import Settings

    limit = re.search(r"client_max_body_size (\d+)k;", conf)
    assert limit and int(limit.group(1)) * 1024 == Settings().max_body_bytes
    read_timeout = int(re.search(r"proxy_read_timeout (\d+)s;", conf).group(1))
    assert read_timeout > Settings().request_timeout_s
    # nginx drops a half-sent request no later than a replica would
    header_timeout = int(re.search(r"client_header_timeout (\d+)s;", conf).group(1))
    body_timeout = int(re.search(r"client_body_timeout (\d+)s;", conf).group(1))
    assert header_timeout <= Settings().header_timeout_s and body_timeout <= Settings().body_timeout_s


@pytest.mark.clients
def test_nginx_accepts_the_config(tmp_path):
    if shutil.which("nginx") is None:
        pytest.skip("nginx is not installed")
    conf = (REPO / "deploy" / "nginx.conf").read_text().replace("server t2m:8000", "server 127.0.0.1:8000")
    (tmp_path / "nginx.conf").write_text(conf)
    result = subprocess.run(["nginx", "-t", "-c", str(tmp_path / "nginx.conf"), "-g", f"pid {tmp_path}/n.pid;"],
                            capture_output=True, text=True)
    assert result.returncode == 0, result.stderr


def test_runtime_imports_need_no_torch():
    """What the image runs (`t2m` parser, app, engine, formats, SDK) imports with torch made unimportable."""
    code = ("import sys; sys.modules['torch'] = None\n"
            "from t2m.cli.main import build_parser; build_parser('serve'); build_parser('generate'); "
            "build_parser('motion')\n"
            "import t2m.service.app, t2m.runtime.engine, t2m.runtime.formats, t2m.motion.gltf, "
            "t2m.motion.bvh_export, t2m.client\n"
            "print('ok')")
    result = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True)
    assert result.returncode == 0 and result.stdout.strip() == "ok", result.stderr[-2000:]


@pytest.mark.parametrize("name", ["docker-compose.yml", "docker-compose.scale.yml"])
def test_compose_files_pass_docker_compose_own_validation(name, tmp_path):
    """`docker-compose config` checks a file against compose's own schema, offline (no engine, no registry). The
    files cannot be brought up here (they need a bridge network and nginx's registry image), so this is what runs."""
    compose = shutil.which("docker-compose")
    if compose is None:
        pytest.skip("docker-compose is not installed (apt-get install docker-compose)")
    ok = subprocess.run([compose, "-f", str(REPO / name), "config", "-q"], capture_output=True, text=True, cwd=REPO)
    assert ok.returncode == 0, ok.stderr
    broken = tmp_path / name
    broken.write_text((REPO / name).read_text().replace("services:", "servicez:", 1))
    bad = subprocess.run([compose, "-f", str(broken), "config", "-q"], capture_output=True, text=True, cwd=REPO)
    assert bad.returncode != 0   # control: the validation does refuse a broken file
