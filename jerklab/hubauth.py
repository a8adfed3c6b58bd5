"""Who is asking: a JupyterHub API token turned into the hub's user name.

A service of the class (the rig broker behind the class page, the class rig service) must not
believe a student ID typed into a page or sent by a kernel: a kernel is the student's own code.
It believes the hub instead. Every student's server (and so every kernel in it) has the
student's own token in ``$JUPYTERHUB_API_TOKEN``; the service sends that token to the hub's
``/hub/api/user`` (:class:`jupyterhub.services.auth.HubAuth`) and gets back the name the hub
logged the student in as. A kernel cannot hold another student's token.

    from jerklab.hubauth import identity_from_token
    name = identity_from_token(token)        # "alice", or HubAuthError

Run as a hub-managed service (``c.JupyterHub.services``), the service has the hub's URL, its
own token and its name in ``$JUPYTERHUB_API_URL``, ``$JUPYTERHUB_API_TOKEN`` and
``$JUPYTERHUB_SERVICE_NAME``; a token is accepted only if it grants
``access:services!service=<name>`` (deploy/jupyterhub/jupyterhub_config.py gives that scope to
the students' servers).
"""

from __future__ import annotations

import os
import re

__all__ = ["HubAuthError", "HubIdentity", "identity_from_token", "token_from_env"]

#: Longest token accepted (JupyterHub's are 32 hex digits; OAuth ones are longer).
_MAX_TOKEN = 512
_TOKEN_RE = re.compile(r"^[A-Za-z0-9._~+/=-]+$")


class HubAuthError(PermissionError):
    """The hub did not identify a user for this token (missing, unknown, expired or not allowed)."""


def token_from_env():
    """The token of this process's hub user (``$JUPYTERHUB_API_TOKEN``), or None outside a hub."""
    return os.environ.get("JUPYTERHUB_API_TOKEN") or None


class HubIdentity:
    """Turns tokens into hub user names, asking the hub once per token per ``cache_max_age`` s.

    Parameters
    ----------
    api_url : str, optional
        The hub's API, e.g. ``http://127.0.0.1:8081/hub/api`` (default ``$JUPYTERHUB_API_URL``).
    api_token : str, optional
        The service's own token (default ``$JUPYTERHUB_API_TOKEN``).
    service_name : str, optional
        The service's name (default ``$JUPYTERHUB_SERVICE_NAME``); when set, the token must grant
        ``access:services!service=<name>``. ``""`` accepts any user token.
    cache_max_age : float
        Seconds an answer of the hub is reused.
    """

    def __init__(self, api_url=None, api_token=None, service_name=None, cache_max_age=60.0):
        from jupyterhub.services.auth import HubAuth

        api_url = api_url or os.environ.get("JUPYTERHUB_API_URL")
        if not api_url:
            raise ValueError("api_url: the hub's API URL is needed (or $JUPYTERHUB_API_URL)")
        api_token = api_token or os.environ.get("JUPYTERHUB_API_TOKEN")
        if not api_token:
            raise ValueError(
                "api_token: the service's hub token is needed (or $JUPYTERHUB_API_TOKEN)"
            )
        if service_name is None:
            service_name = os.environ.get("JUPYTERHUB_SERVICE_NAME", "")
        self.service_name = service_name
        scopes = {f"access:services!service={service_name}"} if service_name else set()
        self._auth = HubAuth(
            api_url=api_url,
            api_token=api_token,
            access_scopes=scopes,
            cache_max_age=int(cache_max_age),
        )

    def __call__(self, token):
        """The hub user name that ``token`` belongs to; :class:`HubAuthError` otherwise."""
        if not isinstance(token, str) or not token:
            raise HubAuthError("token: a JupyterHub token is required (log in through the hub)")
        if len(token) > _MAX_TOKEN or not _TOKEN_RE.match(token):
            raise HubAuthError("token: not a JupyterHub token")
        try:
            model = self._auth.user_for_token(token)
        except Exception as exc:  # the hub unreachable or answering an error
            raise HubAuthError(f"token: the hub could not check it ({type(exc).__name__})") from exc
        if not model or model.get("kind", "user") != "user" or not model.get("name"):
            raise HubAuthError("token: the hub knows no user with this token")
        if self._auth.access_scopes and not self._auth.check_scopes(
            self._auth.access_scopes, model
        ):
            raise HubAuthError(
                f"token: it does not grant access to the service {self.service_name!r}"
            )
        return str(model["name"])


_DEFAULT = None


def identity_from_token(token):
    """The hub user name of ``token``, checked with the hub of this service's environment.

    Parameters
    ----------
    token : str
        A JupyterHub API token (a student's kernel has its own in ``$JUPYTERHUB_API_TOKEN``).

    Returns
    -------
    str
        The user name the hub knows the token's owner by.

    Raises
    ------
    HubAuthError
        No token, a token the hub does not know, a token of a service, or one without
        ``access:services!service=$JUPYTERHUB_SERVICE_NAME``.
    ValueError
        This process is not a hub service (no ``$JUPYTERHUB_API_URL`` / ``$JUPYTERHUB_API_TOKEN``).
    """
    global _DEFAULT
    if _DEFAULT is None:
        _DEFAULT = HubIdentity()
    return _DEFAULT(token)
