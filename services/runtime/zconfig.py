"""A Zenoh configuration file under a service's own settings, and credentials from files or environment.

- ``--zenoh-config FILE`` (or ``CAPATAZ_ZENOH_CONFIG``, else zenoh's own ``ZENOH_CONFIG``) is the base:
  access control, TLS, authentication, anything Zenoh knows. A service's transport settings go on top,
  but only those given explicitly (option or ``CAPATAZ_ZENOH_*`` variable) override a key the file sets;
  the file wins over built-in defaults.
- Credentials never come from the command line: ``CAPATAZ_ZENOH_TLS_CA``, ``CAPATAZ_ZENOH_TLS_CERT``,
  ``CAPATAZ_ZENOH_TLS_KEY`` (PEM files; the certificate and key serve both for listening and connecting,
  mutual TLS on) and ``CAPATAZ_ZENOH_USRPWD_FILE`` (a file holding ``user:password``), or the file's own
  ``transport/link/tls`` and ``transport/auth/usrpwd`` sections.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import zenoh

from common.errors import CapatazError

ENV_CONFIG = "CAPATAZ_ZENOH_CONFIG"
ZENOH_ENV_CONFIG = "ZENOH_CONFIG"


class ZenohConfigError(CapatazError):
    """A Zenoh configuration file or a credential file is missing, unreadable or invalid."""


def config_path_from_env(environ: Mapping[str, str] | None = None) -> Path | None:
    """``CAPATAZ_ZENOH_CONFIG``, else ``ZENOH_CONFIG`` (what zenohd and zenoh tools read), else None."""
    env = os.environ if environ is None else environ
    text = env.get(ENV_CONFIG) or env.get(ZENOH_ENV_CONFIG)
    return Path(text) if text else None


def load_config(path: Path | None) -> zenoh.Config:
    """The file's configuration (JSON5 or YAML, as zenoh reads it), or zenoh's defaults for None."""
    if path is None:
        return zenoh.Config()
    if not Path(path).is_file():
        raise ZenohConfigError(f"zenoh config {path}: no such file")
    try:
        return zenoh.Config.from_file(str(path))
    except Exception as exc:  # zenoh raises ZError with the parser's message
        raise ZenohConfigError(f"zenoh config {path}: {_one_line(exc)}") from None


def get(config: zenoh.Config, key: str) -> Any:
    """The value of ``key`` in ``config`` (decoded JSON)."""
    return json.loads(config.get_json(key))


def file_sets(config: zenoh.Config, key: str) -> bool:
    """Whether ``config`` gives ``key`` a value other than zenoh's default."""
    return bool(config.get_json(key) != zenoh.Config().get_json(key))


def insert(config: zenoh.Config, key: str, value: Any) -> None:
    try:
        config.insert_json5(key, json.dumps(value))
    except Exception as exc:
        raise ZenohConfigError(f"zenoh config {key}={value!r}: {_one_line(exc)}") from None


def _readable(path: Path, what: str) -> str:
    p = Path(path)
    if not p.is_file():
        raise ZenohConfigError(f"{what} {p}: no such file")
    try:
        with p.open("rb") as handle:
            head = handle.read(64)
    except OSError as exc:
        raise ZenohConfigError(f"{what} {p}: {exc.strerror}") from None
    if what != "user/password file" and b"-----BEGIN" not in head:
        raise ZenohConfigError(f"{what} {p}: not a PEM file")
    return str(p.resolve())


def tls_entries(ca: Path | None, cert: Path | None, key: Path | None) -> dict[str, Any]:
    """``transport/link/tls`` for mutual TLS with one certificate for listening and connecting.

    Names are not verified on connect (peers advertise addresses, not names): a link is authenticated by
    the CA, and its certificate's CN is what access control matches.
    """
    if (cert is None) != (key is None):
        raise ZenohConfigError("a TLS certificate needs its private key and vice versa")
    tls: dict[str, Any] = {}
    if ca is not None:
        tls["root_ca_certificate"] = _readable(ca, "TLS CA certificate")
    if cert is not None and key is not None:
        cert_path = _readable(cert, "TLS certificate")
        key_path = _readable(key, "TLS private key")
        tls.update(
            listen_certificate=cert_path,
            listen_private_key=key_path,
            connect_certificate=cert_path,
            connect_private_key=key_path,
            enable_mtls=True,
            verify_name_on_connect=False,
        )
    return {f"transport/link/tls/{k}": v for k, v in tls.items()}


def usrpwd_entries(path: Path | None) -> dict[str, Any]:
    """``transport/auth/usrpwd/{user,password}`` from a ``user:password`` file (first line)."""
    if path is None:
        return {}
    text = Path(_readable(path, "user/password file")).read_text(errors="replace").splitlines()
    user, sep, password = (text[0] if text else "").partition(":")
    if not sep or not user or not password:
        raise ZenohConfigError(f"user/password file {path}: first line must be user:password")
    return {"transport/auth/usrpwd/user": user, "transport/auth/usrpwd/password": password}


def check_tls_ready(config: zenoh.Config, endpoints: list[str]) -> None:
    """A ``tls/`` listen endpoint without a certificate and key fails in zenoh with a bare "Missing TLS
    private key": say what to set instead."""
    if not any(str(e).startswith("tls/") for e in endpoints):
        return
    tls = get(config, "transport/link/tls")
    if not tls.get("listen_private_key") or not tls.get("listen_certificate"):
        raise ZenohConfigError(
            "a tls/ endpoint needs a certificate and key: set CAPATAZ_ZENOH_TLS_CERT and "
            "CAPATAZ_ZENOH_TLS_KEY (and CAPATAZ_ZENOH_TLS_CA), or transport/link/tls in --zenoh-config"
        )


def check_tls_trust(config: zenoh.Config, endpoints: list[str]) -> None:
    """A ``tls/`` connect endpoint without a CA to check the other side's certificate against retried
    forever in silence (zenoh's default roots never trust capataz's CA): say what to set instead."""
    if not any(str(e).startswith("tls/") for e in endpoints):
        return
    if not get(config, "transport/link/tls").get("root_ca_certificate"):
        raise ZenohConfigError(
            "a tls/ connect endpoint needs the CA certificate to trust: set CAPATAZ_ZENOH_TLS_CA (and, for "
            "mutual TLS, CAPATAZ_ZENOH_TLS_CERT and CAPATAZ_ZENOH_TLS_KEY), or transport/link/tls in "
            "--zenoh-config"
        )


def access_control_enabled(config: zenoh.Config) -> bool:
    return bool(get(config, "access_control/enabled"))


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0][:300] if text else type(exc).__name__
