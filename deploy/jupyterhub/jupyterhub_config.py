"""JupyterHub for a jerklab class on one server (docs/INSTRUCTOR.md, "Past one machine").

Every student gets their own Jupyter server (a local process, SimpleLocalProcessSpawner), with
the lab worksheets and the class page copied into their folder on first start, and the class
page at ``/user/<name>/voila/render/tuning.ipynb`` (Voilà as a Jupyter server extension).

Run from the repository root (pip: jupyterhub, nbgitpuller; npm: configurable-http-proxy)::

    JERKLAB_HUB_PASSWORD=class-secret .venv/bin/jupyterhub -f deploy/jupyterhub/jupyterhub_config.py

Environment variables (all optional):

``JERKLAB_HUB_URL``       public URL of the hub (default ``http://127.0.0.1:8000``)
``JERKLAB_HUB_API_URL``   the hub's internal API URL (default ``http://127.0.0.1:8081``)
``JERKLAB_HUB_PROXY_API`` configurable-http-proxy's API URL (default ``http://127.0.0.1:8001``)
``JERKLAB_HUB_STATE``     folder for the database, cookie secret and the students' folders
                          (default ``deploy/jupyterhub/state``)
``JERKLAB_HUB_PASSWORD``  the shared class password of the dummy authenticator; without it any
                          password is accepted (only for a test on localhost)
``JERKLAB_HUB_ADMIN_TOKEN`` an API token for the instructor's scripts (admin of users/servers)
``JERKLAB_RIG_PORT``      the rig behind the class page (as ``python -m jerklab.app --rig``)

SimpleLocalProcessSpawner runs every student's server as the hub's own Unix user, in a folder
of its own: fine for a lab room behind a firewall. For real accounts use the Littlest JupyterHub
(one server, system users) or Zero to JupyterHub (deploy/z2jh/values.yaml).
"""

import os
import pathlib
import shutil

c = get_config()  # noqa: F821 (injected by jupyterhub)

REPO = pathlib.Path(__file__).resolve().parents[2]
STATE = pathlib.Path(os.environ.get("JERKLAB_HUB_STATE", REPO / "deploy" / "jupyterhub" / "state"))
STATE.mkdir(parents=True, exist_ok=True)
HOMES = STATE / "home"

# ------------------------------------------------------------------ URLs, state
c.JupyterHub.bind_url = os.environ.get("JERKLAB_HUB_URL", "http://127.0.0.1:8000")
c.JupyterHub.hub_bind_url = os.environ.get("JERKLAB_HUB_API_URL", "http://127.0.0.1:8081")
c.ConfigurableHTTPProxy.api_url = os.environ.get("JERKLAB_HUB_PROXY_API", "http://127.0.0.1:8001")
c.ConfigurableHTTPProxy.should_start = True
c.JupyterHub.db_url = f"sqlite:///{STATE / 'jupyterhub.sqlite'}"
c.JupyterHub.cookie_secret_file = str(STATE / "jupyterhub_cookie_secret")
c.ConfigurableHTTPProxy.pid_file = str(STATE / "jupyterhub-proxy.pid")

# ------------------------------------------------------------------ who
c.JupyterHub.authenticator_class = "dummy"
if os.environ.get("JERKLAB_HUB_PASSWORD"):
    c.DummyAuthenticator.password = os.environ["JERKLAB_HUB_PASSWORD"]
c.Authenticator.allow_all = True
c.Authenticator.admin_users = {"instructor"}

if os.environ.get("JERKLAB_HUB_ADMIN_TOKEN"):
    c.JupyterHub.services = [
        {"name": "jerklab-admin", "api_token": os.environ["JERKLAB_HUB_ADMIN_TOKEN"]}
    ]
    c.JupyterHub.load_roles = [
        {
            "name": "jerklab-admin",
            "services": ["jerklab-admin"],
            "scopes": ["admin:users", "admin:servers", "tokens", "access:servers"],
        }
    ]

# ------------------------------------------------------------------ the students' servers
c.JupyterHub.spawner_class = "simple"  # jupyterhub.spawner.SimpleLocalProcessSpawner
c.SimpleLocalProcessSpawner.home_dir_template = str(HOMES / "{username}")
c.Spawner.default_url = "/lab"
c.Spawner.http_timeout = 120
c.Spawner.start_timeout = 120
c.Spawner.environment = {
    # jerklab from this checkout (or drop this line when jerklab is pip-installed)
    "PYTHONPATH": str(REPO),
    "JERKLAB_RIG_PORT": os.environ.get("JERKLAB_RIG_PORT", ""),
    "MPLBACKEND": "Agg",
}
c.Spawner.args = [
    # idle kernels are shut down after 15 min, an idle server after 1 h: 30 students' kernels
    # (~0.3 GB each) do not pile up after the lesson
    "--MappingKernelManager.cull_idle_timeout=900",
    "--MappingKernelManager.cull_interval=60",
    "--MappingKernelManager.cull_connected=False",
    "--ServerApp.shutdown_no_activity_timeout=3600",
]
if hasattr(os, "geteuid") and os.geteuid() == 0:
    # a hub run as root (a container, CI): the local spawner starts the servers as root too
    c.Spawner.args.append("--allow-root")

WORKSHEETS = [REPO / "notebooks", REPO / "app" / "tuning.ipynb"]


def copy_worksheets(spawner):
    """First start of a student's server: copy the lab worksheets and the class page.

    An existing file is never overwritten (a student's work stays). nbgitpuller links do the
    same from a git repository (docs/INSTRUCTOR.md).
    """
    home = pathlib.Path(spawner.home_dir_template.format(username=spawner.user.name))
    home.mkdir(parents=True, exist_ok=True)
    for src in WORKSHEETS:
        if src.is_dir():
            for nb in sorted(src.glob("*.ipynb")):
                dst = home / nb.name
                if not dst.exists():
                    shutil.copy2(nb, dst)
        elif src.is_file() and not (home / src.name).exists():
            shutil.copy2(src, home / src.name)


c.Spawner.pre_spawn_hook = copy_worksheets
