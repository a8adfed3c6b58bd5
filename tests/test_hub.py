"""deploy/jupyterhub/jupyterhub_config.py: a hub with the dummy authenticator and the local
process spawner; two students log in (API tokens), their servers start with the worksheets in
their folder, and a lab cell runs in a kernel of each (jerklab with the virtual rig).

Needs jupyterhub (pip) and configurable-http-proxy (npm); skips without them (fails in CI).
"""

import json
import os
import pathlib
import secrets
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
import uuid

import pytest
from conftest import require_tool

pytestmark = pytest.mark.slow

ROOT = pathlib.Path(__file__).resolve().parent.parent
CONFIG = ROOT / "deploy" / "jupyterhub" / "jupyterhub_config.py"
LAB_CELL = """\
import os, jerklab
from jerklab.rig import connect
rig = connect(None, progress=False)
print("LAB", os.environ.get("JUPYTERHUB_USER"), type(rig).__name__,
      sorted(f for f in os.listdir(".") if f.endswith(".ipynb"))[:3])
"""


# Keys of the Zero to JupyterHub chart's values schema (jupyterhub/values.schema.yaml, chart 3.x
# and 4.x) that deploy/z2jh/values.yaml may use; a typo in a key is silently ignored by Helm.
Z2JH_KEYS = {
    "hub": {"config": None, "extraConfig": None, "extraEnv": None, "db": None, "resources": None},
    "singleuser": {
        "image": {"name": None, "tag": None, "pullPolicy": None},
        "defaultUrl": None,
        "memory": {"guarantee": None, "limit": None},
        "cpu": {"guarantee": None, "limit": None},
        "storage": {"capacity": None, "type": None, "homeMountPath": None},
        "extraEnv": None,
        "lifecycleHooks": None,
        "cmd": None,
        "profileList": None,
        "startTimeout": None,
    },
    "cull": {
        "enabled": None,
        "timeout": None,
        "every": None,
        "users": None,
        "maxAge": None,
        "concurrency": None,
        "removeNamedServers": None,
        "adminUsers": None,
    },
    "prePuller": {"hook": {"enabled": None}, "continuous": {"enabled": None}},
    "scheduling": {
        "userScheduler": {"enabled": None},
        "podPriority": {"enabled": None},
        "userPlaceholder": {"enabled": None, "replicas": None},
    },
    "proxy": None,
    "ingress": None,
}


def _check_keys(values, schema, path=""):
    for key, val in values.items():
        assert key in schema, f"{path}{key} is not a key of the z2jh chart"
        if isinstance(schema[key], dict):
            assert isinstance(val, dict), f"{path}{key} must be a mapping"
            _check_keys(val, schema[key], f"{path}{key}.")


def test_z2jh_values_file():
    yaml = pytest.importorskip("yaml")
    values = yaml.safe_load((ROOT / "deploy" / "z2jh" / "values.yaml").read_text())
    _check_keys(values, Z2JH_KEYS)
    cfg = values["hub"]["config"]
    assert cfg["JupyterHub"]["authenticator_class"] == "dummy"
    # the same culling intent as the one-server hub
    assert values["cull"]["enabled"] is True and values["cull"]["timeout"] > 0
    hook = " ".join(values["singleuser"]["lifecycleHooks"]["postStart"]["exec"]["command"])
    assert "gitpuller" in hook and "environment.txt" in hook
    assert values["singleuser"]["extraEnv"]["PYTHONPATH"] == "/home/jovyan/jerklab"
    # a student's memory limit holds two kernels of ~0.3 GB (benchmarks/bench_class.py)
    lim = values["singleuser"]["memory"]["limit"]
    assert lim.endswith("G") and float(lim[:-1]) >= 0.6


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _api(url, token, method="GET", body=None, timeout=30):
    data = json.dumps(body).encode() if body is not None else (b"" if method == "POST" else None)
    req = urllib.request.Request(
        url,
        data=data,
        method=method,
        headers={"Authorization": f"token {token}", "Content-Type": "application/json"},
    )
    with urllib.request.urlopen(req, timeout=timeout) as r:
        txt = r.read().decode()
        return r.status, (json.loads(txt) if txt.strip().startswith(("{", "[")) else txt)


@pytest.fixture(scope="module")
def hub(tmp_path_factory):
    pytest.importorskip("jupyterhub")
    require_tool("configurable-http-proxy")
    state = tmp_path_factory.mktemp("hub")
    port, api, proxy = _free_port(), _free_port(), _free_port()
    token = secrets.token_hex(16)
    env = dict(
        os.environ,
        JERKLAB_HUB_URL=f"http://127.0.0.1:{port}",
        JERKLAB_HUB_API_URL=f"http://127.0.0.1:{api}",
        JERKLAB_HUB_PROXY_API=f"http://127.0.0.1:{proxy}",
        JERKLAB_HUB_STATE=str(state),
        JERKLAB_HUB_ADMIN_TOKEN=token,
        PATH=os.path.dirname(sys.executable) + os.pathsep + os.environ["PATH"],
    )
    log = open(state / "hub.log", "w")
    proc = subprocess.Popen(
        [sys.executable, "-m", "jupyterhub", "-f", str(CONFIG)],
        cwd=state,
        env=env,
        stdout=log,
        stderr=subprocess.STDOUT,
        start_new_session=True,
    )
    base = f"http://127.0.0.1:{port}"
    try:
        t0 = time.monotonic()
        while True:
            try:
                _api(base + "/hub/api/", token)
                break
            except (OSError, urllib.error.URLError):
                if proc.poll() is not None or time.monotonic() - t0 > 90:
                    pytest.fail("hub did not start:\n" + (state / "hub.log").read_text()[-3000:])
                time.sleep(0.5)
        yield base, token, state
    finally:
        try:
            os.killpg(proc.pid, signal.SIGTERM)
            proc.wait(30)
        except Exception:
            os.killpg(proc.pid, signal.SIGKILL)
        log.close()


def _run_cell(base, user, token, code, timeout=90):
    """Start a kernel on the user's server, execute ``code``, return its stdout."""
    import websocket  # websocket-client

    _, kernel = _api(f"{base}/user/{user}/api/kernels", token, "POST", {"name": "python3"})
    try:
        ws = websocket.create_connection(
            f"{base.replace('http', 'ws')}/user/{user}/api/kernels/{kernel['id']}/channels",
            header=[f"Authorization: token {token}"],
            timeout=timeout,
        )
        msg_id = uuid.uuid4().hex
        ws.send(
            json.dumps(
                {
                    "header": {
                        "msg_id": msg_id,
                        "username": user,
                        "session": uuid.uuid4().hex,
                        "msg_type": "execute_request",
                        "version": "5.3",
                    },
                    "parent_header": {},
                    "metadata": {},
                    "channel": "shell",
                    "content": {
                        "code": code,
                        "silent": False,
                        "store_history": False,
                        "user_expressions": {},
                        "allow_stdin": False,
                    },
                }
            )
        )
        out, t0 = [], time.monotonic()
        while time.monotonic() - t0 < timeout:
            msg = json.loads(ws.recv())
            if msg.get("parent_header", {}).get("msg_id") != msg_id:
                continue
            kind = msg["header"]["msg_type"]
            if kind == "stream":
                out.append(msg["content"]["text"])
            elif kind == "error":
                raise AssertionError("\n".join(msg["content"]["traceback"]))
            elif kind == "status" and msg["content"]["execution_state"] == "idle":
                return "".join(out)
        raise AssertionError(f"no reply in {timeout} s")
    finally:
        _api(f"{base}/user/{user}/api/kernels/{kernel['id']}", token, "DELETE")


def test_two_students_run_a_lab_cell(hub):
    base, admin, state = hub
    users = ["alice", "bob"]
    tokens = {}
    for u in users:
        status, _ = _api(f"{base}/hub/api/users/{u}", admin, "POST")
        assert status == 201
        # the student's own token ("logging in" by API); the admin service may create it
        _, tok = _api(f"{base}/hub/api/users/{u}/tokens", admin, "POST", {"note": "test"})
        tokens[u] = tok["token"]
    for u in users:  # each student starts their own server with their own token
        status, _ = _api(f"{base}/hub/api/users/{u}/server", tokens[u], "POST")
        assert status in (201, 202)
    t0 = time.monotonic()
    for u in users:
        while True:
            _, info = _api(f"{base}/hub/api/users/{u}", admin)
            if info["servers"].get("", {}).get("ready"):
                break
            assert time.monotonic() - t0 < 150, f"{u}'s server not ready: {info}"
            time.sleep(1.0)
    for u in users:
        out = _run_cell(base, u, tokens[u], LAB_CELL)
        assert out.startswith(f"LAB {u} "), out
        assert "01_" in out or ".ipynb" in out, out  # the worksheets were copied
        assert (state / "home" / u / "tuning.ipynb").is_file()
    # a student cannot reach another student's server
    with pytest.raises(urllib.error.HTTPError) as err:
        _api(f"{base}/user/alice/api/kernels", tokens["bob"])
    assert err.value.code in (403, 404)
    # the class page is served to a student by Voilà (server extension)
    status, page = _api(
        f"{base}/user/alice/voila/render/tuning.ipynb", tokens["alice"], timeout=180
    )
    assert status == 200 and "kernelId" in page
