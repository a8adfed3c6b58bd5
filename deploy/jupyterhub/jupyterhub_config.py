"""JupyterHub for a jerklab class on one server (docs/INSTRUCTOR.md, "Past one machine").

Each student is only themselves:

* a login of their own (FirstUseAuthenticator with a password per student set beforehand by
  ``deploy/jupyterhub/roster.py``, so no first use is left to take; only the roster's names
  may log in) and an instructor (admin) with a password of its own;
* a Unix user of their own (LocalProcessSpawner with system users, as the Littlest JupyterHub
  does): a student's server and kernels run as that user, in a home of mode 0700, so they read
  neither a classmate's files nor the hub's environment, cookie secret or database (the hub's
  state folder is 0700 for root, the hub's user);
* the class page's rig broker, when there is a rig (``JERKLAB_RIG_PORT``), runs as a hub
  service under a Unix user of its own and believes only hub tokens (``--hub-auth``): a run is
  recorded under the name the hub logged the student in as.

Set up and run as root from the repository root (pip: jupyterhub,
jupyterhub-firstuseauthenticator; npm: configurable-http-proxy)::

    sudo .venv/bin/python deploy/jupyterhub/roster.py roster.txt --state /srv/jerklab-hub
    sudo JERKLAB_HUB_STATE=/srv/jerklab-hub JERKLAB_HUB_ROSTER=roster.txt \\
         .venv/bin/jupyterhub -f deploy/jupyterhub/jupyterhub_config.py

Environment variables:

``JERKLAB_HUB_ROSTER``    the roster file, one user name a line (required)
``JERKLAB_HUB_STATE``     folder for the database, cookie secret and passwords (required;
                          made 0700)
``JERKLAB_HUB_ADMIN``     the instructor's login (default ``instructor``)
``JERKLAB_HUB_URL``       public URL of the hub (default ``http://127.0.0.1:8000``)
``JERKLAB_HUB_API_URL``   the hub's internal API URL (default ``http://127.0.0.1:8081``)
``JERKLAB_HUB_PROXY_API`` configurable-http-proxy's API URL (default ``http://127.0.0.1:8001``)
``JERKLAB_HUB_ADMIN_TOKEN`` an API token for the instructor's scripts (admin of users/servers)
``JERKLAB_RIG_PORT``      the rig behind the class page (as ``python -m jerklab.broker --rig``);
                          unset: every kernel has its own virtual rig
``JERKLAB_HUB_BROKER_PORT`` the broker's TCP port on 127.0.0.1 (default 8867)
``JERKLAB_HUB_BROKER_USER`` the broker's Unix user (default ``jerklab-rig``, made if missing,
                          home ``/var/lib/jerklab-rig`` holding its copy of every run)
``JERKLAB_HUB_CLASS_RIG`` the class rig service's address (``python -m jerklab.lab service``,
                          e.g. ``classrig://127.0.0.1:7341``): set as ``JERKLAB_CLASS_RIG`` in
                          every student's server, so ``lab.start(N)`` runs on the graded
                          motor with nothing typed (the service knows the student from the
                          server's hub token); unset: practice motors
"""

import os
import pathlib
import pwd
import re
import subprocess
import sys

c = get_config()  # noqa: F821 (injected by jupyterhub)

REPO = pathlib.Path(__file__).resolve().parents[2]
BIN = pathlib.Path(sys.executable).parent


def _required(name):
    value = os.environ.get(name)
    if not value:
        raise SystemExit(f"jerklab hub: set {name} (see deploy/jupyterhub/jupyterhub_config.py)")
    return value


if os.geteuid() != 0:
    raise SystemExit(
        "jerklab hub: run the hub as root: it starts each student's server as their own Unix user"
    )

STATE = pathlib.Path(_required("JERKLAB_HUB_STATE"))
STATE.mkdir(parents=True, exist_ok=True)
os.chown(STATE, 0, 0)
os.chmod(STATE, 0o700)  # database, cookie secret, passwords: the hub's user only

ROSTER = pathlib.Path(_required("JERKLAB_HUB_ROSTER"))
_NAME = re.compile(r"^[a-z][a-z0-9_-]{0,31}$")
STUDENTS = set()
for _line in ROSTER.read_text(encoding="utf-8").splitlines():
    _name = _line.split("#", 1)[0].strip()
    if _name:
        if not _NAME.match(_name):
            raise SystemExit(f"jerklab hub: {ROSTER}: {_name!r} is not a user name")
        STUDENTS.add(_name)
ADMIN = os.environ.get("JERKLAB_HUB_ADMIN", "instructor")

# ------------------------------------------------------------------ URLs, state
c.JupyterHub.bind_url = os.environ.get("JERKLAB_HUB_URL", "http://127.0.0.1:8000")
c.JupyterHub.hub_bind_url = os.environ.get("JERKLAB_HUB_API_URL", "http://127.0.0.1:8081")
c.ConfigurableHTTPProxy.api_url = os.environ.get("JERKLAB_HUB_PROXY_API", "http://127.0.0.1:8001")
c.ConfigurableHTTPProxy.should_start = True
c.JupyterHub.db_url = f"sqlite:///{STATE / 'jupyterhub.sqlite'}"
c.JupyterHub.cookie_secret_file = str(STATE / "jupyterhub_cookie_secret")
c.ConfigurableHTTPProxy.pid_file = str(STATE / "jupyterhub-proxy.pid")

# ------------------------------------------------------------------ who
# one password per student, made by roster.py before the hub starts: FirstUseAuthenticator with
# no "first use" left (the hub refuses to start while a roster name has no password)
c.JupyterHub.authenticator_class = "firstuseauthenticator.FirstUseAuthenticator"
PASSWORDS = STATE / "passwords.dbm"
c.FirstUseAuthenticator.dbm_path = str(PASSWORDS)
c.FirstUseAuthenticator.create_users = False  # only the hub's users (the roster) log in
c.FirstUseAuthenticator.min_password_length = 10
c.FirstUseAuthenticator.check_passwords_on_startup = False


def _without_password(names):
    import dbm

    try:
        with dbm.open(str(PASSWORDS), "r") as db:
            return sorted(n for n in names if n.encode("utf-8") not in db)
    except dbm.error:
        return sorted(names)


_missing = _without_password(STUDENTS | {ADMIN})
if _missing:
    raise SystemExit(
        f"jerklab hub: no password yet for {', '.join(_missing)}: run "
        f"deploy/jupyterhub/roster.py {ROSTER} --state {STATE} first"
    )
c.Authenticator.allow_all = False
c.Authenticator.allowed_users = STUDENTS
c.Authenticator.admin_users = {ADMIN}

# the broker service (below) may identify the students' servers' tokens
BROKER = "jerklab-rig"
_SERVER_SCOPES = ["users:activity!user", "access:servers!server"]
c.JupyterHub.load_roles = [
    {"name": "user", "scopes": ["self", f"access:services!service={BROKER}"]},
]
c.Spawner.server_token_scopes = _SERVER_SCOPES + [f"access:services!service={BROKER}"]

c.JupyterHub.services = []
if os.environ.get("JERKLAB_HUB_ADMIN_TOKEN"):
    c.JupyterHub.services.append(
        {"name": "jerklab-admin", "api_token": os.environ["JERKLAB_HUB_ADMIN_TOKEN"]}
    )
    c.JupyterHub.load_roles.append(
        {
            "name": "jerklab-admin",
            "services": ["jerklab-admin"],
            "scopes": ["admin:users", "admin:servers", "tokens", "access:servers"],
        }
    )

# ------------------------------------------------------------------ the class page's rig
RIG = os.environ.get("JERKLAB_RIG_PORT", "")
BROKER_ADDRESS = ""
if RIG:
    port = int(os.environ.get("JERKLAB_HUB_BROKER_PORT", "8867"))
    user = os.environ.get("JERKLAB_HUB_BROKER_USER", "jerklab-rig")
    try:
        pw = pwd.getpwnam(user)
    except KeyError:
        subprocess.run(
            [
                "useradd",
                "--system",
                "--create-home",
                "--home-dir",
                f"/var/lib/{user}",
                "--shell",
                "/usr/sbin/nologin",
                "--user-group",
                user,
            ],
            check=True,
        )
        pw = pwd.getpwnam(user)
    rig_home = pathlib.Path(pw.pw_dir)
    rig_home.mkdir(parents=True, exist_ok=True)
    os.chown(rig_home, pw.pw_uid, pw.pw_gid)
    os.chmod(rig_home, 0o700)  # its recordings: the broker's own copies
    BROKER_ADDRESS = f"broker://127.0.0.1:{port}"
    c.JupyterHub.services.append(
        {
            "name": BROKER,
            "user": user,
            "cwd": str(rig_home),
            "command": [
                sys.executable,
                "-m",
                "jerklab.broker",
                f"--rig={RIG}",
                f"--port={port}",
                "--hub-auth",
                f"--recordings={rig_home / 'recordings'}",
            ],
            "environment": {"PYTHONPATH": str(REPO)},
        }
    )

# ------------------------------------------------------------------ the students' servers
c.JupyterHub.spawner_class = "jupyterhub.spawner.LocalProcessSpawner"
c.Spawner.cmd = [str(BIN / "jupyterhub-singleuser")]
c.Spawner.default_url = "/lab"
c.Spawner.http_timeout = 120
c.Spawner.start_timeout = 120
c.Spawner.environment = {
    # jerklab from this checkout (or drop this line when jerklab is pip-installed)
    "PYTHONPATH": str(REPO),
    "JERKLAB_RIG_PORT": BROKER_ADDRESS,
    "MPLBACKEND": "Agg",
}
CLASS_RIG = os.environ.get("JERKLAB_HUB_CLASS_RIG", "").strip()
if CLASS_RIG:
    if not CLASS_RIG.startswith(("classrig://", "classrig+unix://")):
        raise SystemExit(
            f"jerklab hub: JERKLAB_HUB_CLASS_RIG must be classrig://HOST:PORT or "
            f"classrig+unix:///PATH (python -m jerklab.lab service), got {CLASS_RIG!r}"
        )
    # the graded hidden motors: every student's kernel reaches the class rig service
    c.Spawner.environment["JERKLAB_CLASS_RIG"] = CLASS_RIG
c.Spawner.args = [
    # idle kernels are shut down after 15 min, an idle server after 1 h: 30 students' kernels
    # (~0.3 GB each) do not pile up after the lesson
    "--MappingKernelManager.cull_idle_timeout=900",
    "--MappingKernelManager.cull_interval=60",
    "--MappingKernelManager.cull_connected=False",
    "--ServerApp.shutdown_no_activity_timeout=3600",
    # the class page: no tracebacks (server paths) on a student's page
    "--VoilaConfiguration.show_tracebacks=False",
    # a kernel websocket without the v1 protocol, or with a malformed frame, is refused: it
    # would spin the server at 100 % CPU, deaf to SIGTERM (jerklab._voila_guard)
    "--ServerApp.kernel_websocket_connection_class=jerklab._voila_guard.GuardedKernelConnection",
]

WORKSHEETS = [REPO / "notebooks", REPO / "app" / "tuning.ipynb"]


def copy_worksheets(spawner):
    """First start of a student's server: copy the worksheets and the class page, as theirs.

    An existing file is never overwritten (a student's work stays). nbgitpuller links do the
    same from a git repository (docs/INSTRUCTOR.md).
    """
    pw = pwd.getpwnam(spawner.user.name)
    home = pathlib.Path(pw.pw_dir)
    os.chmod(home, 0o700)
    for src in WORKSHEETS:
        files = sorted(src.glob("*.ipynb")) if src.is_dir() else [src] if src.is_file() else []
        for nb in files:
            # O_EXCL: never through a file or link the student put there (the hub is root)
            try:
                fd = os.open(home / nb.name, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
            except FileExistsError:
                continue
            with os.fdopen(fd, "wb") as out:
                os.fchown(out.fileno(), pw.pw_uid, pw.pw_gid)
                out.write(nb.read_bytes())


c.Spawner.pre_spawn_hook = copy_worksheets
