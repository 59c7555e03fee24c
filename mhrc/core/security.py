"""Zenoh's own security for one run (docs/architecture.md, "Security"): TLS links, user/password
authentication and access-control rules on the world's router.

`make_run_credentials` writes, into one directory (0700; files 0600, `ca.pem` 0644); `load`
refuses a key or password file others can read, or in a folder others can write (ExposedSecret):

- `ca.pem`: the run's certificate authority (its private key is never written: nobody can
  sign another certificate for this run once the files exist);
- `world.pem` / `world.key`: the world's server certificate (SAN 127.0.0.1, localhost and any
  `hosts` the agents reach it by, e.g. a compose service name);
- `users.txt`: the zenoh user/password dictionary (`user:password` per line), the world's only;
- `<user>.json` per participant (`world`, each robot, `observer`): its run, user name,
  password and the files it may read. Each participant gets only its own;
- `.gitignore` (`*`): a credentials directory written inside a checkout is never committed.

With `split`, each participant's files go to a directory of its own (`mhrc credentials --split`,
for containers: each mounts only its own). `mhrc up` calls this for every secured run;
`mhrc credentials` for a world and agents started by hand or by docker compose.

The world's router (`apply(conf, creds, router=True)`) listens on TLS with its certificate,
authenticates every client against the dictionary (`transport/auth/usrpwd/dictionary_file`)
and enforces `access_control` (default deny): a robot's user may publish only its own
robot's request, thought and generating keys, query its own attach key, declare its own liveliness token
and subscribe to what an agent needs. A denied message is dropped by the router.

Why a client session was refused (`why_refused`) is told by mhrc.core.refusal. cryptography
(mhrc.core.certs) is imported only where certificates are written or read: `--insecure` never loads it.
"""

from __future__ import annotations

import datetime
import json
import os
import secrets
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NotRequired, TypedDict

from mhrc.core.participants import OBSERVER, WORLD, reserved_why

ENV = "MHRC_CREDENTIALS"
GITIGNORE = "# written by mhrc: credentials are secrets, never to be committed\n*\n"  # in every credentials directory
RUN = "run"  # the only kind of credentials: one run's participants (an evaluation's job queue, kind "eval", is gone: mhrc eval --ray)


class SecurityError(RuntimeError):
    """Credentials that are missing, unreadable or refused; the message names the cause."""

    code = "credentials"


class ExposedSecret(SecurityError):
    """A key or password file others can read (or a folder others can write into, where they could
    swap one): refused, as ssh refuses a private key others can read. The message says the chmod."""

    code = "exposed_secret"


MIN_DAYS = (
    1 / 1440
)  # a minute, mhrc credentials --days' least: certificates that expire before the world and its agents meet are a typo


def check_private(path: Path) -> None:
    """Raise ExposedSecret if `path` (a key or password file) is readable or writable by others
    than its owner, or its folder is writable by them; checked on load, before anything uses it."""
    try:
        mode = path.stat().st_mode & 0o777
        folder = path.parent.stat().st_mode & 0o777
    except OSError:
        return  # its absence or unreadability is said by the caller
    if mode & 0o077:
        raise ExposedSecret(f"{path} holds a secret but others can access it (mode {mode:04o}): run chmod 600 {path}")
    if folder & 0o022:
        raise ExposedSecret(
            f"{path.parent}, which holds the secret {path.name}, is writable by others (mode {folder:04o}): "
            f"run chmod 700 {path.parent}"
        )


# ---------------------------------------------------------------------------------- credentials
@dataclass(frozen=True)
class Credentials:
    """One participant's credentials for one run."""

    run: str
    user: str
    password: str
    ca: Path  # the run's CA certificate, that the world's certificate must chain to
    robots: tuple[str, ...] = ()
    cert: Path | None = None  # the world's certificate, key and user dictionary
    key: Path | None = None
    users: Path | None = None
    path: Path | None = None  # the file these came from
    kind: str = RUN

    @property
    def is_world(self) -> bool:
        """The credentials of the participant whose router the others log in to."""
        return self.user == WORLD

    def describe(self) -> str:
        return f"user {self.user!r} of run {self.run!r}" + (f" ({self.path})" if self.path else "")


class CredentialsFile(TypedDict):
    """A participant's `<user>.json`, as `make_run_credentials` writes it and `load` reads it
    (paths relative to the file; the world's alone has its certificate, key and users)."""

    run: str
    user: str
    password: str
    ca: str
    robots: list[str]
    cert: NotRequired[str]
    key: NotRequired[str]
    users: NotRequired[str]


def make_run_credentials(
    run: str,
    robots: Sequence[str],
    directory: Path,
    *,
    days: float = 7.0,
    observer: bool = True,
    hosts: Sequence[str] = (),
    split: bool = False,
) -> dict[str, Path]:
    """Generate a CA, the world's certificate (for 127.0.0.1, localhost and `hosts`) and one
    user per participant into `directory`; returns each user's credentials file.

    With `split`, each participant's files go to a directory of its own (DIR/alice/alice.json
    beside its own copy of ca.pem; DIR/world/ also holds the certificate, key and user
    dictionary), to be mounted into that participant's container and no other."""
    from mhrc.core.keys import check_id

    check_id(run, "run id")
    for r in robots:
        check_id(r, "robot")
        if (why := reserved_why(r)) is not None:  # before anything is written: a robot `world` took the world's key
            raise SecurityError(f"robot {r!r}: no robot may be called that: {why}")
    users = [WORLD, *robots] + ([OBSERVER] if observer else [])
    return _issue(run, users, directory, robots=robots, days=days, hosts=hosts, split=split)


def _issue(
    run: str,
    users: Sequence[str],
    directory: Path,
    *,
    robots: Sequence[str] = (),
    days: float,
    hosts: Sequence[str],
    split: bool = False,
) -> dict[str, Path]:
    """Write a CA, the server's (users[0]'s) certificate and a login per user; each user's
    files go to `directory`, or to a directory of its own with `split`."""
    directory.mkdir(parents=True, exist_ok=True)
    os.chmod(directory, 0o700)
    from mhrc.core.certs import make_ca, make_server_cert, pem_cert, pem_key, write_private

    write_private(directory / ".gitignore", GITIGNORE)  # `git add -A` in a checkout must never take a private key
    ca, ca_key = make_ca(run, days=days)
    cert, key = make_server_cert(ca, ca_key, days=days, hosts=hosts)
    server = users[0]
    passwords = {u: secrets.token_urlsafe(24) for u in users}

    def home(user: str) -> Path:
        if not split:
            return directory
        d = directory / user
        d.mkdir(exist_ok=True)
        os.chmod(d, 0o700)
        return d

    out: dict[str, Path] = {}
    with_ca: set[Path] = set()
    for u in users:
        d = home(u)
        if d not in with_ca:  # once per directory: all of them share it flat, each has its own split
            write_private(d / "ca.pem", pem_cert(ca), private=False)
            with_ca.add(d)
        entry: CredentialsFile = {
            "run": run,
            "user": u,
            "password": passwords[u],
            "ca": "ca.pem",
            "robots": list(robots),
        }
        if u == server:
            write_private(d / f"{u}.pem", pem_cert(cert))
            write_private(d / f"{u}.key", pem_key(key))
            write_private(d / "users.txt", "".join(f"{name}:{pw}\n" for name, pw in passwords.items()))
            entry |= {"cert": f"{u}.pem", "key": f"{u}.key", "users": "users.txt"}
        out[u] = write_private(d / f"{u}.json", json.dumps(entry, indent=2) + "\n")
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
            kind=str(data.get("kind", RUN)),
        )
    except FileNotFoundError:
        raise SecurityError(f"credentials file {p} does not exist") from None
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise SecurityError(f"credentials file {p} is unreadable or malformed: {exc!r}") from None
    for f in (creds.ca, creds.cert, creds.key, creds.users):
        if f is not None and not f.is_file():
            raise SecurityError(f"credentials file {p} names {f}, which does not exist")
    for secret in (p, creds.key, creds.users):  # the password, the world's private key, every participant's password
        if secret is not None:
            check_private(secret)
    if creds.kind != RUN:
        raise SecurityError(
            f"credentials file {p}: kind {creds.kind!r} is not a run's (an evaluation needs no credentials any more: "
            "mhrc eval runs locally, or on Ray with --ray)"
        )
    if creds.is_world and (creds.cert is None or creds.key is None or creds.users is None):
        raise SecurityError(f"credentials file {p}: the {creds.user} needs cert, key and users")
    for f in (creds.ca, creds.cert):
        if f is not None:
            _check_current(f, p)
    return creds


def _check_current(pem: Path, source: Path) -> None:
    """Raise unless the certificate in `pem` is valid now (not expired, not yet valid)."""
    from cryptography import x509

    try:
        cert = x509.load_pem_x509_certificate(pem.read_bytes())
    except (OSError, ValueError) as exc:
        raise SecurityError(f"credentials file {source} names {pem}, which is not a PEM certificate ({exc})") from None
    now = datetime.datetime.now(datetime.timezone.utc)
    if cert.not_valid_after_utc < now:
        raise SecurityError(
            f"the certificate {pem} (of {source}) expired on {cert.not_valid_after_utc:%Y-%m-%d %H:%M} UTC: "
            "issue new credentials (mhrc credentials, or mhrc up makes fresh ones)"
        )
    if cert.not_valid_before_utc > now:
        raise SecurityError(
            f"the certificate {pem} (of {source}) is not valid before {cert.not_valid_before_utc:%Y-%m-%d %H:%M} UTC"
        )


def expiry(creds: Credentials) -> datetime.datetime | None:
    """When the first of the run's certificates this participant holds (the CA's, and the world's
    own) stops being valid; None if none can be read."""
    from cryptography import x509

    ends = []
    for pem in (creds.ca, creds.cert):
        if pem is not None:
            try:
                ends.append(x509.load_pem_x509_certificate(pem.read_bytes()).not_valid_after_utc)
            except (OSError, ValueError):
                continue
    return min(ends, default=None)


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
class AclRule(TypedDict):
    """One rule of zenoh's `access_control`: which messages, which way, on which keys."""

    id: str
    messages: list[str]
    flows: list[str]
    permission: str
    key_exprs: list[str]


class AclSubject(TypedDict):
    id: str
    usernames: list[str]


class AclPolicy(TypedDict):
    """Which rules apply to which subjects."""

    id: str
    rules: list[str]
    subjects: list[str]


class AccessControl(TypedDict):
    """zenoh's `access_control` configuration, as `acl` writes it."""

    enabled: bool
    default_permission: str
    rules: list[AclRule]
    subjects: list[AclSubject]
    policies: list[AclPolicy]


def acl(run: str, robots: Sequence[str]) -> AccessControl:
    """The world router's `access_control`: default deny. Only the world's user speaks for the
    world: it alone may put world events, acks, results, turns and inbox copies, reply to
    queries and hold `alive/world`. The observer reads the whole run (and may ask `world/state`),
    and every robot reads the world's events and liveliness; a robot sends only its own requests
    and thoughts (and generating status), queries only its own attach key and holds only its own liveliness token.

    Zenoh matches a rule by key inclusion: a declaration is allowed when its key expression lies
    inside one of the rule's, a message when its key does. Ingress is what a client sends to the
    router, egress what the router sends to that client."""
    base = f"mhrc/{run}"
    events = [f"{base}/world/event", f"{base}/alive/world", "mhrc/*/alive/world"]  # anyone logged in reads these
    rules: list[AclRule] = [
        {
            "id": "world-all",
            "messages": [
                "put",
                "delete",
                "declare_subscriber",
                "query",
                "reply",
                "declare_queryable",
                "liveliness_token",
                "liveliness_query",
                "declare_liveliness_subscriber",
            ],
            "flows": ["ingress", "egress"],
            "permission": "allow",
            "key_exprs": [f"{base}/**"],
        },
        {  # what the observer receives: everything of the run, and replies to its world/state queries
            "id": "observer-receive",
            "messages": [
                "put",
                "delete",
                "liveliness_token",
                "reply",
                "declare_subscriber",
                "declare_queryable",
                "declare_liveliness_subscriber",
            ],
            "flows": ["egress"],
            "permission": "allow",
            "key_exprs": [f"{base}/**"],
        },
        {  # what the observer may ask for: subscriptions anywhere under mhrc/ (the router carries this run only, and
            # egress filters what reaches it) and the world's state; it sends nothing of its own
            "id": "observer-ask",
            "messages": ["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query"],
            "flows": ["ingress"],
            "permission": "allow",
            "key_exprs": ["mhrc/**"],
        },
        {
            "id": "observer-query",
            "messages": ["query"],
            "flows": ["ingress"],
            "permission": "allow",
            "key_exprs": [f"{base}/world/state"],
        },
        {  # every login may watch the world's events and liveliness (find_run, an agent's world watch), never speak there
            "id": "world-events-watch",
            "messages": ["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query"],
            "flows": ["ingress"],
            "permission": "allow",
            "key_exprs": events,
        },
        {
            "id": "world-events-receive",
            "messages": ["put", "liveliness_token"],
            "flows": ["egress"],
            "permission": "allow",
            "key_exprs": events,
        },
        {  # the world's (and the recorder's) subscriptions and queryables, wildcards included: without them a
            # client's declared publisher sees no subscriber and sends nothing
            "id": "declarations-visible",
            "messages": ["declare_subscriber", "declare_queryable"],
            "flows": ["egress"],
            "permission": "allow",
            "key_exprs": [f"{base}/**"],
        },
    ]
    subjects: list[AclSubject] = [
        {"id": "s-world", "usernames": [WORLD]},
        {"id": "s-observer", "usernames": [OBSERVER]},
        {"id": "s-robots", "usernames": list(robots)},
    ]
    policies: list[AclPolicy] = [
        {"id": "p-world", "rules": ["world-all"], "subjects": ["s-world"]},
        {
            "id": "p-observer",
            "rules": [
                "observer-receive",
                "observer-ask",
                "observer-query",
                "world-events-watch",
                "world-events-receive",
            ],
            "subjects": ["s-observer"],
        },
        {
            "id": "p-visible",
            "rules": ["world-events-watch", "world-events-receive", "declarations-visible"],
            "subjects": ["s-robots"],
        },
    ]
    for r in robots:
        k = f"{base}/robot/{r}"
        own_put, own_in, own_out = f"{r}-put", f"{r}-in", f"{r}-out"
        rules += [
            {  # what robot r may send: its requests, thoughts and generating status
                "id": own_put,
                "messages": ["put"],
                "flows": ["ingress"],
                "permission": "allow",
                "key_exprs": [f"{k}/action/request", f"{base}/agent/{r}/thought", f"{base}/agent/{r}/generating"],
            },
            {  # its attach query, its liveliness token, its subscriptions to what the world sends it
                "id": own_in,
                "messages": ["query", "liveliness_token", "declare_subscriber"],
                "flows": ["ingress"],
                "permission": "allow",
                "key_exprs": [
                    f"{k}/attach",
                    f"{base}/alive/robot/{r}",
                    f"{k}/action/ack",
                    f"{k}/action/result",
                    f"{k}/turn",
                    f"{k}/inbox/**",
                ],
            },
            {  # what robot r may receive: its acks, results, turns, messages and attach replies
                "id": own_out,
                "messages": ["put", "reply", "declare_subscriber", "declare_queryable", "liveliness_token"],
                "flows": ["egress"],
                "permission": "allow",
                "key_exprs": [
                    f"{k}/**",
                    f"{base}/agent/{r}/thought",
                    f"{base}/agent/{r}/generating",
                    f"{base}/alive/robot/{r}",
                ],
            },
        ]
        subjects.append({"id": f"s-{r}", "usernames": [r]})
        policies.append({"id": f"p-{r}", "rules": [own_put, own_in, own_out], "subjects": [f"s-{r}"]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects, "policies": policies}


def apply(conf: Any, creds: Credentials, *, router: bool) -> None:
    """Insert TLS, user/password authentication and (on the world's router) access control
    into the zenoh.Config `conf`."""

    def put(key: str, value: object) -> None:
        conf.insert_json5(key, json.dumps(value))

    put("transport/link/tls/root_ca_certificate", str(creds.ca))
    put("transport/link/tls/verify_name_on_connect", True)
    put("transport/link/tls/close_link_on_expiration", True)
    if router:
        if not creds.is_world:
            raise SecurityError(f"only the world's credentials can serve the bus, not {creds.describe()}")
        put("transport/link/tls/listen_certificate", str(creds.cert))
        put("transport/link/tls/listen_private_key", str(creds.key))
        put("transport/auth/usrpwd/dictionary_file", str(creds.users))
        put("access_control", acl(creds.run, creds.robots))
    else:
        put("transport/auth/usrpwd/user", creds.user)
        put("transport/auth/usrpwd/password", creds.password)
