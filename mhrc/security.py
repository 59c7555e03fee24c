"""Zenoh's own security for one run (DESIGN.md, "Security"): TLS links, user/password
authentication and access-control rules on the world's router.

`make_run_credentials` writes, into one directory (files 0600):

- `ca.pem`: the run's certificate authority (its private key is never written: nobody can
  sign another certificate for this run once the files exist);
- `world.pem` / `world.key`: the world's server certificate (SAN 127.0.0.1, localhost);
- `users.txt`: the zenoh user/password dictionary (`user:password` per line), the world's only;
- `<user>.json` per participant (`world`, each robot, `observer`): its run, user name,
  password and the files it may read. Each participant gets only its own.

The world's router (`apply(conf, creds, router=True)`) listens on TLS with its certificate,
authenticates every client against the dictionary (`transport/auth/usrpwd/dictionary_file`)
and enforces `access_control` (default deny): a robot's user may publish only its own
robot's request and thought keys, query its own attach key, declare its own liveliness token
and subscribe to what an agent needs. A denied message is dropped by the router.
"""

from __future__ import annotations

import datetime
import ipaddress
import json
import os
import secrets
import socket
import ssl
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import NameOID

ENV = "MHRC_CREDENTIALS"
WORLD = "world"
OBSERVER = "observer"  # subscribes to everything of the run, publishes nothing (the recorder of `mhrc up --processes`)


class SecurityError(RuntimeError):
    """Credentials that are missing, unreadable or refused; the message names the cause."""


# ---------------------------------------------------------------------------------- certificates
def _key() -> ec.EllipticCurvePrivateKey:
    return ec.generate_private_key(ec.SECP256R1())


def _pem_key(key: ec.EllipticCurvePrivateKey) -> bytes:
    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption())


def _pem_cert(cert: x509.Certificate) -> bytes:
    return cert.public_bytes(serialization.Encoding.PEM)


def make_ca(name: str, *, days: float = 7.0) -> tuple[x509.Certificate, ec.EllipticCurvePrivateKey]:
    """A self-signed certificate authority `mhrc <name> CA`."""
    key = _key()
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, f"mhrc {name} CA")])
    now = datetime.datetime.now(datetime.timezone.utc)
    cert = (
        x509.CertificateBuilder()
        .subject_name(subject)
        .issuer_name(subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=days))
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(
            x509.KeyUsage(False, False, False, False, False, True, True, False, False), critical=True
        )  # key_cert_sign, crl_sign
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
        .sign(key, hashes.SHA256())
    )
    return cert, key


def make_server_cert(
    ca: x509.Certificate,
    ca_key: ec.EllipticCurvePrivateKey,
    *,
    name: str = "localhost",
    days: float = 7.0,
    not_before: datetime.datetime | None = None,
) -> tuple[x509.Certificate, ec.EllipticCurvePrivateKey]:
    """A server certificate signed by `ca` for 127.0.0.1 and localhost (`not_before` and a
    negative `days` make an expired one, for tests)."""
    key = _key()
    start = not_before or datetime.datetime.now(datetime.timezone.utc) - datetime.timedelta(minutes=5)
    cert = (
        x509.CertificateBuilder()
        .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)]))
        .issuer_name(ca.subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(start)
        .not_valid_after(start + datetime.timedelta(days=days))
        .add_extension(
            x509.SubjectAlternativeName([x509.DNSName("localhost"), x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]),
            critical=False,
        )
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(x509.ExtendedKeyUsage([x509.oid.ExtendedKeyUsageOID.SERVER_AUTH]), critical=False)
        .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False)
        .sign(ca_key, hashes.SHA256())
    )
    return cert, key


def _write(path: Path, data: bytes | str, private: bool = True) -> Path:
    """Write `data`, created 0600 (never readable by others, even for a moment) when private."""
    raw = data.encode() if isinstance(data, str) else data
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600 if private else 0o644)
    try:
        os.write(fd, raw)
    finally:
        os.close(fd)
    if private:
        os.chmod(path, 0o600)
    return path


# ---------------------------------------------------------------------------------- credentials
@dataclass(frozen=True)
class Credentials:
    """One participant's credentials for one run."""

    run: str
    user: str
    password: str
    ca: Path  # the run's CA certificate, that the world's certificate must chain to
    robots: tuple[str, ...] = ()
    cert: Path | None = None  # the world's server certificate, key and user dictionary
    key: Path | None = None
    users: Path | None = None
    path: Path | None = None  # the file these came from

    @property
    def is_world(self) -> bool:
        return self.user == WORLD

    def describe(self) -> str:
        return f"user {self.user!r} of run {self.run!r}" + (f" ({self.path})" if self.path else "")


def make_run_credentials(
    run: str,
    robots: Sequence[str],
    directory: Path,
    *,
    days: float = 7.0,
    observer: bool = True,
) -> dict[str, Path]:
    """Generate a CA, the world's certificate and one user per participant into `directory`;
    returns each user's credentials file."""
    from .keys import check_id

    check_id(run, "run id")
    for r in robots:
        check_id(r, "robot")
    directory.mkdir(parents=True, exist_ok=True)
    os.chmod(directory, 0o700)
    ca, ca_key = make_ca(run, days=days)
    cert, key = make_server_cert(ca, ca_key, days=days)
    ca_path = _write(directory / "ca.pem", _pem_cert(ca), private=False)
    cert_path = _write(directory / "world.pem", _pem_cert(cert))
    key_path = _write(directory / "world.key", _pem_key(key))
    users = [WORLD, *robots] + ([OBSERVER] if observer else [])
    passwords = {u: secrets.token_urlsafe(24) for u in users}
    users_path = _write(directory / "users.txt", "".join(f"{u}:{p}\n" for u, p in passwords.items()))
    out: dict[str, Path] = {}
    for u in users:
        entry: dict[str, Any] = {"run": run, "user": u, "password": passwords[u], "ca": ca_path.name, "robots": list(robots)}
        if u == WORLD:
            entry.update(cert=cert_path.name, key=key_path.name, users=users_path.name)
        out[u] = _write(directory / f"{u}.json", json.dumps(entry, indent=2) + "\n")
    return out


def load(path: Path | str) -> Credentials:
    """Read one participant's credentials file (paths in it are relative to the file)."""
    p = Path(path)
    try:
        data = json.loads(p.read_text())
        base = p.parent

        def rel(name: str | None) -> Path | None:
            return None if name is None else (base / name).resolve()

        creds = Credentials(
            run=str(data["run"]),
            user=str(data["user"]),
            password=str(data["password"]),
            ca=rel(data["ca"]),  # type: ignore[arg-type]
            robots=tuple(data.get("robots", ())),
            cert=rel(data.get("cert")),
            key=rel(data.get("key")),
            users=rel(data.get("users")),
            path=p,
        )
    except FileNotFoundError:
        raise SecurityError(f"credentials file {p} does not exist") from None
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise SecurityError(f"credentials file {p} is unreadable or malformed: {exc!r}") from None
    for f in (creds.ca, creds.cert, creds.key, creds.users):
        if f is not None and not f.is_file():
            raise SecurityError(f"credentials file {p} names {f}, which does not exist")
    if creds.is_world and (creds.cert is None or creds.key is None or creds.users is None):
        raise SecurityError(f"credentials file {p}: the world needs cert, key and users")
    return creds


def from_env_or(path: Path | str | None) -> Credentials | None:
    """Credentials from `path`, else from the file named by $MHRC_CREDENTIALS, else None."""
    chosen = path or os.environ.get(ENV) or None
    return None if chosen is None else load(chosen)


def check_for(creds: Credentials, *, run: str | None = None, user: str | None = None) -> None:
    """Raise unless `creds` are for `run` and `user` (when given)."""
    if run is not None and creds.run != run:
        raise SecurityError(f"the credentials {creds.describe()} are for run {creds.run!r}, not {run!r}")
    if user is not None and creds.user != user:
        raise SecurityError(f"the credentials {creds.describe()} are {creds.user!r}'s, not {user!r}'s")


# ---------------------------------------------------------------------------------- zenoh config
def acl(run: str, robots: Sequence[str]) -> dict[str, Any]:
    """The world router's `access_control`: default deny; the world and the observer have the
    run's key space (the observer to read only), each robot only its own keys."""
    base = f"mhrc/{run}"
    rules: list[dict[str, Any]] = [
        {
            "id": "world-all",
            "messages": ["put", "delete", "declare_subscriber", "query", "reply", "declare_queryable",
                         "liveliness_token", "liveliness_query", "declare_liveliness_subscriber"],
            "flows": ["ingress", "egress"],
            "permission": "allow",
            "key_exprs": [f"{base}/**"],
        },
        {
            "id": "observer-read",
            "messages": ["declare_subscriber", "put", "delete", "liveliness_token", "liveliness_query", "declare_liveliness_subscriber",
                         "query", "reply"],
            "flows": ["egress"],
            "permission": "allow",
            "key_exprs": [f"{base}/**"],
        },
        {
            "id": "observer-subscribe",
            "messages": ["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query"],
            "flows": ["ingress"],
            "permission": "allow",
            "key_exprs": [f"{base}/**", "mhrc/*/alive/world"],
        },
        {  # anyone authenticated may see the world's liveliness (find_run) and its events
            "id": "world-visible",
            "messages": ["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query", "put", "liveliness_token"],
            "flows": ["ingress", "egress"],
            "permission": "allow",
            "key_exprs": [f"{base}/world/event", f"{base}/alive/world", "mhrc/*/alive/world"],
        },
        {  # the world's (and the recorder's) subscriptions and queryables, wildcards included: without them a
            # client's declared publisher sees no subscriber and sends nothing
            "id": "declarations-visible",
            "messages": ["declare_subscriber", "declare_queryable"],
            "flows": ["egress"],
            "permission": "allow",
            "key_exprs": [f"{base}/**"],
        },
    ]  # fmt: skip
    subjects: list[dict[str, Any]] = [
        {"id": "s-world", "usernames": [WORLD]},
        {"id": "s-observer", "usernames": [OBSERVER]},
        {"id": "s-robots", "usernames": list(robots)},
    ]
    policies: list[dict[str, Any]] = [
        {"id": "p-world", "rules": ["world-all"], "subjects": ["s-world"]},
        {"id": "p-observer", "rules": ["observer-read", "observer-subscribe", "world-visible"], "subjects": ["s-observer"]},
        {"id": "p-visible", "rules": ["world-visible", "declarations-visible"], "subjects": ["s-robots"]},
    ]
    for r in robots:
        k = f"{base}/robot/{r}"
        own_in = f"{r}-in"
        own_out = f"{r}-out"
        own_put = f"{r}-put"
        rules += [
            {  # what robot r may send: its requests and thoughts, its attach query, its liveliness
                "id": own_put,
                "messages": ["put"],
                "flows": ["ingress"],
                "permission": "allow",
                "key_exprs": [f"{k}/action/request", f"{base}/agent/{r}/thought"],
            },
            {
                "id": own_in,
                "messages": ["query", "liveliness_token", "declare_subscriber"],
                "flows": ["ingress"],
                "permission": "allow",
                "key_exprs": [f"{k}/attach", f"{base}/alive/robot/{r}", f"{k}/action/ack", f"{k}/action/result", f"{k}/turn",
                              f"{k}/inbox/**"],
            },
            {  # what robot r may receive: its acks, results, turns, messages and attach replies
                "id": own_out,
                "messages": ["put", "reply", "declare_subscriber", "declare_queryable", "liveliness_token"],
                "flows": ["egress"],
                "permission": "allow",
                "key_exprs": [f"{k}/**", f"{base}/agent/{r}/thought", f"{base}/alive/robot/{r}"],
            },
        ]  # fmt: skip
        subjects.append({"id": f"s-{r}", "usernames": [r]})
        policies.append({"id": f"p-{r}", "rules": [own_put, own_in, own_out], "subjects": [f"s-{r}"]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects, "policies": policies}


def apply(conf: Any, creds: Credentials, *, router: bool) -> None:
    """Insert TLS, user/password authentication and (on the world's router) access control
    into the zenoh.Config `conf`."""

    def put(key: str, value: Any) -> None:
        conf.insert_json5(key, json.dumps(value))

    put("transport/link/tls/root_ca_certificate", str(creds.ca))
    put("transport/link/tls/verify_name_on_connect", True)
    put("transport/link/tls/close_link_on_expiration", True)
    if router:
        if not creds.is_world:
            raise SecurityError(f"only the world's credentials can serve the run's bus, not {creds.describe()}")
        put("transport/link/tls/listen_certificate", str(creds.cert))
        put("transport/link/tls/listen_private_key", str(creds.key))
        put("transport/auth/usrpwd/dictionary_file", str(creds.users))
        put("access_control", acl(creds.run, creds.robots))
    else:
        put("transport/auth/usrpwd/user", creds.user)
        put("transport/auth/usrpwd/password", creds.password)


# ---------------------------------------------------------------------------------- diagnosis
def diagnose(endpoint: str, creds: Credentials | None, timeout: float = 3.0) -> str:
    """Why a client session to `endpoint` could not open, as far as a plain TLS handshake with
    the run's CA can tell: nothing listening, a plain tcp world, an expired or foreign
    certificate, or (the handshake succeeding) credentials the world refused."""
    proto, _, addr = endpoint.partition("/")
    host, _, port_s = addr.rpartition(":")
    try:
        port = int(port_s)
    except ValueError:
        return f"bad endpoint {endpoint!r}"
    try:
        raw = socket.create_connection((host, port), timeout=timeout)
    except OSError as exc:
        return f"nothing accepts connections on {host}:{port} ({exc.strerror or exc})"
    with raw:
        if creds is None:
            if proto == "tls":
                return "the endpoint is tls but no credentials were given (--credentials or $MHRC_CREDENTIALS)"
            return "the world refused an open connection: it probably requires credentials (--credentials or $MHRC_CREDENTIALS)"
        if proto != "tls":
            return f"credentials were given but the endpoint {endpoint} is not tls/"
        ctx = ssl.create_default_context(cafile=str(creds.ca))
        try:
            with ctx.wrap_socket(raw, server_hostname=host) as tls:
                tls.do_handshake()
        except ssl.SSLCertVerificationError as exc:
            why = exc.verify_message or str(exc)
            if "expired" in why:
                return f"the world's certificate has expired ({why})"
            if "issuer" in why or "self-signed" in why or "self signed" in why:
                return (
                    f"the world's certificate is not signed by the CA of {creds.describe()} ({why}): "
                    "a foreign certificate, or a world of another run"
                )
            return f"the world's certificate was rejected: {why}"
        except ssl.SSLError as exc:
            return f"the TLS handshake failed: {exc.reason or exc} (is the world listening on plain tcp?)"
        except OSError as exc:
            return f"the TLS handshake failed: {exc}"
    return (
        f"the TLS link is sound but the world refused the login of {creds.describe()}: "
        "a wrong password, or credentials of another run"
    )
