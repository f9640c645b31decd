"""Zenoh's own security for a session: TLS (mutual, with a private CA), user/password authentication, and
a pass-through Zenoh configuration file (docs/bus.md, "Security").

One directory per identity holds what a session needs (``deploy/make-certs.sh`` writes them):

- ``ca.pem``: the CA that signed every certificate of the deployment; peers are checked against it;
- ``cert.pem``, ``key.pem``: this identity's certificate and key, presented as TLS server (a router's
  listener) and as TLS client (every session: the router requires client certificates);
- ``credentials``: one line ``user:password``, this identity's Zenoh login;
- ``users`` (routers only): ``user:password`` lines, the logins the router accepts.

Without a directory (the default, one host on loopback) sessions are plain TCP, as they always were.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import zenoh

FILES = ("ca.pem", "cert.pem", "key.pem", "credentials")
USERS = "users"


class SecurityError(Exception):
    """A security directory or Zenoh configuration file that cannot be used; the message is one line."""


@dataclass(frozen=True)
class Security:
    """What a session proves and checks; picklable, so that forked node processes inherit it."""

    ca: str
    cert: str
    key: str
    user: str
    password: str
    users: str | None = None  # the router's dictionary of accepted logins

    @classmethod
    def from_dir(cls, folder: str | Path) -> Security:
        path = Path(folder)
        missing = [name for name in FILES if not (path / name).is_file()]
        if missing:
            raise SecurityError(f"{path}: missing {', '.join(missing)} (expected {', '.join(FILES)}; "
                                "deploy/make-certs.sh writes them)")
        user, sep, password = (path / "credentials").read_text().strip().partition(":")
        if not sep or not user or not password:
            raise SecurityError(f"{path / 'credentials'}: expected one line user:password")
        users = path / USERS
        return cls(str((path / "ca.pem").resolve()), str((path / "cert.pem").resolve()),
                   str((path / "key.pem").resolve()), user, password,
                   str(users.resolve()) if users.is_file() else None)

    def settings(self) -> dict[str, Any]:
        """Zenoh configuration entries (path -> value) for a session with this identity."""
        tls = "transport/link/tls/"
        out: dict[str, Any] = {
            tls + "root_ca_certificate": self.ca,
            tls + "enable_mtls": True,
            tls + "listen_certificate": self.cert,
            tls + "listen_private_key": self.key,
            tls + "connect_certificate": self.cert,
            tls + "connect_private_key": self.key,
            "transport/auth/usrpwd/user": self.user,
            "transport/auth/usrpwd/password": self.password,
        }
        if self.users is not None:
            out["transport/auth/usrpwd/dictionary_file"] = self.users
        return out


PROTOCOL = {False: "tcp", True: "tls"}


def protocol(security: Security | None) -> str:
    """The endpoint protocol a router listens with."""
    return PROTOCOL[security is not None]


def file_overrides(path: str | Path) -> dict[str, Any]:
    """The settings of a Zenoh JSON5 configuration file that differ from Zenoh's defaults, as
    (path -> value): merged last into a generated configuration, so that the file wins where it speaks."""
    try:
        given = json.loads(str(zenoh.Config.from_file(str(path))))
    except Exception as exc:  # zenoh.ZError: unreadable file, bad JSON5, unknown key
        raise SecurityError(f"{path}: not a usable Zenoh configuration: {exc}") from None
    return _differences(given, json.loads(str(zenoh.Config())), "")


def _differences(given: Any, default: Any, prefix: str) -> dict[str, Any]:
    if isinstance(given, dict) and isinstance(default, dict):
        out: dict[str, Any] = {}
        for key, value in given.items():
            out.update(_differences(value, default.get(key), f"{prefix}{key}/"))
        return out
    return {} if given == default else {prefix.rstrip("/"): given}
