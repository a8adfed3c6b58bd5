"""deploy/jupyterhub/jupyterhub_config.py: a hub with a login per student and a Unix user per
student (tests/_hub.py); two students start their servers (API tokens), which hold the
worksheets in their own home, a lab cell runs in a kernel of each (jerklab with the virtual
rig), and the class page is served. The attacks on the same hub: tests/security/test_hub.py.

Needs root, jupyterhub, jupyterhub-firstuseauthenticator (pip) and configurable-http-proxy
(npm); skips without them (fails in CI).
"""

import json
import pathlib
import pwd
import urllib.error

import pytest
from _hub import CLASS_RIG, api, run_cell, running_hub

pytestmark = pytest.mark.slow

ROOT = pathlib.Path(__file__).resolve().parent.parent
LAB_CELL = """\
import os, jerklab
from jerklab.rig import connect
rig = connect(None, progress=False)
print("LAB", os.environ.get("JUPYTERHUB_USER"), type(rig).__name__,
      sorted(f for f in os.listdir(".") if f.endswith(".ipynb"))[:3],
      "CLASS_RIG=" + os.environ.get("JERKLAB_CLASS_RIG", ""))
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
    # a login per student, approved by the instructor; no shared class password
    assert cfg["JupyterHub"]["authenticator_class"] == "nativeauthenticator.NativeAuthenticator"
    assert "DummyAuthenticator" not in cfg and "dummy" not in json.dumps(cfg).lower()
    assert cfg["NativeAuthenticator"]["open_signup"] is False
    assert cfg["Authenticator"]["allow_all"] is False and cfg["Authenticator"]["allowed_users"]
    # the same culling intent as the one-server hub
    assert values["cull"]["enabled"] is True and values["cull"]["timeout"] > 0
    hook = " ".join(values["singleuser"]["lifecycleHooks"]["postStart"]["exec"]["command"])
    assert "gitpuller" in hook and "environment.txt" in hook
    assert values["singleuser"]["extraEnv"]["PYTHONPATH"] == "/home/jovyan/jerklab"
    # a student's memory limit holds two kernels of ~0.3 GB (benchmarks/bench_class.py)
    lim = values["singleuser"]["memory"]["limit"]
    assert lim.endswith("G") and float(lim[:-1]) >= 0.6


@pytest.fixture(scope="module")
def hub():
    with running_hub(["jlt-ana", "jlt-ben"], admin="jlt-teacher") as h:
        yield h


def test_two_students_run_a_lab_cell(hub):
    users = ["jlt-ana", "jlt-ben"]
    tokens = {u: hub.user_token(u) for u in users}
    for u in users:  # each student starts their own server with their own token
        hub.start_server(u, tokens[u])
    for u in users:
        out = run_cell(hub.base, u, tokens[u], LAB_CELL)
        assert out.startswith(f"LAB {u} "), out
        assert f"CLASS_RIG={CLASS_RIG}" in out, out  # the graded service, nothing typed
        assert "01_" in out or ".ipynb" in out, out  # the worksheets were copied
        home = pathlib.Path(pwd.getpwnam(u).pw_dir)
        st = (home / "tuning.ipynb").stat()
        assert st.st_uid == pwd.getpwnam(u).pw_uid  # theirs, to edit
        assert home.stat().st_mode & 0o777 == 0o700
    # a student cannot reach another student's server
    with pytest.raises(urllib.error.HTTPError) as err:
        api(f"{hub.base}/user/jlt-ana/api/kernels", tokens["jlt-ben"])
    assert err.value.code in (403, 404)
    # the class page is served to a student by Voila (server extension)
    status, page = api(
        f"{hub.base}/user/jlt-ana/voila/render/tuning.ipynb", tokens["jlt-ana"], timeout=180
    )
    assert status == 200 and "kernelId" in page


def _load_config(tmp_path, monkeypatch, **env):
    """deploy/jupyterhub/jupyterhub_config.py read as the hub reads it (root; a roster of one
    with its password made), without starting a hub; its traitlets config."""
    import dbm
    import os

    from traitlets.config import Config

    if os.geteuid() != 0:
        pytest.skip("the hub's config runs as root only")
    roster = tmp_path / "roster.txt"
    roster.write_text("ann\n")
    state = tmp_path / "state"
    state.mkdir()
    with dbm.open(str(state / "passwords.dbm"), "c") as db:
        db[b"ann"] = db[b"instructor"] = b"x"
    for k in ("JERKLAB_RIG_PORT", "JERKLAB_HUB_ADMIN_TOKEN", "JERKLAB_HUB_CLASS_RIG"):
        monkeypatch.delenv(k, raising=False)
    monkeypatch.setenv("JERKLAB_HUB_STATE", str(state))
    monkeypatch.setenv("JERKLAB_HUB_ROSTER", str(roster))
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    c = Config()
    path = ROOT / "deploy" / "jupyterhub" / "jupyterhub_config.py"
    exec(
        compile(path.read_text(), str(path), "exec"),
        {"get_config": lambda: c, "__file__": str(path)},
    )
    return c


def test_config_hands_every_server_the_class_rig(tmp_path, monkeypatch):
    c = _load_config(tmp_path, monkeypatch, JERKLAB_HUB_CLASS_RIG="classrig://127.0.0.1:7341")
    assert c.Spawner.environment["JERKLAB_CLASS_RIG"] == "classrig://127.0.0.1:7341"
    (tmp_path / "b").mkdir()
    c = _load_config(tmp_path / "b", monkeypatch)  # no service: practice motors
    assert "JERKLAB_CLASS_RIG" not in c.Spawner.environment
    (tmp_path / "c").mkdir()
    with pytest.raises(SystemExit, match="JERKLAB_HUB_CLASS_RIG must be classrig://"):
        _load_config(tmp_path / "c", monkeypatch, JERKLAB_HUB_CLASS_RIG="http://127.0.0.1:7341")


def test_roster_names_are_plain_unix_user_names(tmp_path):
    """deploy/jupyterhub/roster.py takes one plain user name a line; anything else is refused
    naming the line (a name like ``../x`` or ``root:0`` never reaches useradd)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(
        "jerklab_roster", ROOT / "deploy" / "jupyterhub" / "roster.py"
    )
    roster = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(roster)
    good = tmp_path / "good.txt"
    good.write_text("# class A\ns1234\n\nana-b  # a comment\nx_9\n")
    assert roster.read_roster(good) == ["s1234", "ana-b", "x_9"]
    for text, why in [
        ("s1\n../etc\n", "line 2"),
        ("Root\n", "line 1"),
        ("a b\n", "line 1"),
        ("-rf\n", "line 1"),
        ("s1\ns1\n", "listed twice"),
        ("x" * 33 + "\n", "line 1"),
        ("# nobody\n", "lists no user"),
    ]:
        bad = tmp_path / "bad.txt"
        bad.write_text(text)
        with pytest.raises(ValueError, match=why):
            roster.read_roster(bad)
