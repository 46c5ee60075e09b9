"""One way for every formation-cbf process to build its ``zenoh.Config``.

Command line -> :class:`ZenohSettings` (frozen, typed) -> ``zenoh.Config``::

    parser = argparse.ArgumentParser()
    add_zenoh_args(parser)
    ns = parser.parse_args()
    with zenoh.open(config_from_args(ns)) as session:
        ...

Zenoh 1.x configuration keys this module sets (each checked against zenoh-python 1.10 by
inserting it and opening a session; ``Config.insert_json5`` rejects unknown keys):

=================================  ==========================================================
key                                value
=================================  ==========================================================
``mode``                           ``"peer"``, ``"client"`` or ``"router"``
``connect/endpoints``              list of ``<proto>/<address>``, e.g. ``tcp/127.0.0.1:7447``
``listen/endpoints``               list of endpoints (zenoh's default is mode-dependent)
``scouting/multicast/enabled``     ``false`` unless asked for (multicast scouting off)
``connect/timeout_ms``             how long ``zenoh.open`` keeps retrying its connect
                                   endpoints (a client fails at once by default)
``scouting/delay``                 how long a peer or router ``zenoh.open`` waits for scouting
                                   (zenoh's default makes it take about 0.5 s; a router
                                   started by :mod:`runtime.router` sets 0)
``transport/auth/usrpwd/user``,    user/password authentication (:class:`UsrPwdAuth`; see its
``.../password``,                  TODO)
``.../dictionary_file``
=================================  ==========================================================

Multicast scouting is off by default because a warehouse network (and CI) should only talk to
the endpoints it names; turn it on with ``multicast_scouting=True`` / ``--multicast-scouting``.

Zenoh's threads: by default a zenoh-python session runs five async runtimes (``app``, ``rx``,
``tx``, ``acc``, ``net``) on their own worker threads, so one message in or out wakes two or three
threads. With dozens of agents on a few cores those wake-ups are most of the cost of a message.
:func:`use_zenoh_threads` sets the ``ZENOH_RUNTIME`` environment variable (which Zenoh reads when
its runtime starts) to one of two profiles, unless the user set it to something else:

* ``"agent"``: every runtime handed over to ``app``, one worker thread for the whole session. The
  agent ticks on that thread (the pose callback) and its puts go out when the tick returns, so a
  tick's messages leave in one write. Safe because the agent's publishers drop rather than block
  under congestion (Zenoh's default): a put never waits for the thread it runs on.
* ``"relay"`` (router, world, launcher): receiving handed over to ``app``, sending kept on its
  own ``tx`` thread. A router on one thread deadlocked: forwarding a fragmented message (over
  64 kB) from a publisher with blocking congestion control waited for queue space that only the
  same thread could free, and it forwarded nothing after that.

Fewer threads woken means fewer context switches per message and less CPU per agent
(docs/performance.md, "The message path of a fleet"). Every formation-cbf entry point calls it
before its first session.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import socket
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal, get_args

import zenoh

from wire import keys

logger = logging.getLogger(__name__)

Mode = Literal["peer", "client", "router"]
MODES: tuple[str, ...] = get_args(Mode)


@dataclass(frozen=True, slots=True)
class UsrPwdAuth:
    """User/password authentication of zenoh transports (``transport/auth/usrpwd``).

    ``formation run`` gives each process its own (access control, :mod:`wire.acl`); client
    commands read theirs from a file with ``--auth FILE`` (:func:`read_auth_file`); deploy
    installs one per robot in its ``zenoh.json5``. It never travels in ``to_argv``.
    """

    user: str
    password: str
    dictionary_file: str | None = None  # a router's ``user:password`` lines


@dataclass(frozen=True, slots=True)
class ZenohSettings:
    """Typed Zenoh session settings; :meth:`to_config` builds the ``zenoh.Config``."""

    mode: Mode = "peer"
    connect: tuple[str, ...] = ()
    listen: tuple[str, ...] = ()
    multicast_scouting: bool = False
    connect_timeout_s: float | None = None  # None: zenoh's default for the mode [s]
    scouting_delay_s: float | None = None  # None: zenoh's default (0.5 s in 1.10) [s]
    config_file: str | None = None  # a zenoh JSON5 file to start from
    auth: UsrPwdAuth | None = None

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"mode {self.mode!r} must be one of {MODES}")
        for name in ("connect", "listen"):
            value = getattr(self, name)
            if isinstance(value, str):
                raise ValueError(f"{name} must be a sequence of endpoints, not a single str")
            endpoints = tuple(value)
            for endpoint in endpoints:
                if not isinstance(endpoint, str) or "/" not in endpoint:
                    raise ValueError(
                        f"{name} endpoint {endpoint!r} must look like <proto>/<address>"
                    )
            object.__setattr__(self, name, endpoints)
        if not isinstance(self.multicast_scouting, bool):
            raise ValueError(f"multicast_scouting must be a bool, got {self.multicast_scouting!r}")
        for name in ("connect_timeout_s", "scouting_delay_s"):
            value = getattr(self, name)
            if value is not None and (
                isinstance(value, bool)
                or not isinstance(value, int | float)
                or not math.isfinite(value)
                or value < 0
            ):
                raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")

    def to_config(self) -> zenoh.Config:
        """Build the ``zenoh.Config``; ``ValueError`` naming the setting zenoh rejects."""
        if self.config_file is not None:
            try:
                conf = zenoh.Config.from_file(self.config_file)
            except Exception as exc:  # noqa: BLE001 - zenoh.ZError: unreadable or not JSON5
                raise ValueError(f"config_file {self.config_file!r}: {exc}") from None
        else:
            conf = zenoh.Config()
        _insert(conf, "mode", self.mode, "mode")
        if self.connect:
            _insert(conf, "connect/endpoints", list(self.connect), "connect")
        if self.listen:
            _insert(conf, "listen/endpoints", list(self.listen), "listen")
        _insert(conf, "scouting/multicast/enabled", self.multicast_scouting, "multicast_scouting")
        if self.connect_timeout_s is not None:
            timeout_ms = round(self.connect_timeout_s * 1000.0)
            _insert(conf, "connect/timeout_ms", timeout_ms, "connect_timeout_s")
        if self.scouting_delay_s is not None:
            delay_ms = round(self.scouting_delay_s * 1000.0)
            _insert(conf, "scouting/delay", delay_ms, "scouting_delay_s")
        if self.auth is not None:
            _insert(conf, "transport/auth/usrpwd/user", self.auth.user, "auth.user")
            _insert(conf, "transport/auth/usrpwd/password", self.auth.password, "auth.password")
            if self.auth.dictionary_file is not None:
                _insert(
                    conf,
                    "transport/auth/usrpwd/dictionary_file",
                    self.auth.dictionary_file,
                    "auth.dictionary_file",
                )
        return conf

    def to_argv(self) -> list[str]:
        """Command-line flags that :func:`add_zenoh_args` parses back into these settings.

        For launchers that start child processes; ``auth`` is not passed on the command line.
        """
        argv = ["--mode", self.mode]
        for endpoint in self.connect:
            argv += ["--connect", endpoint]
        for endpoint in self.listen:
            argv += ["--listen", endpoint]
        argv.append(
            "--multicast-scouting" if self.multicast_scouting else "--no-multicast-scouting"
        )
        if self.connect_timeout_s is not None:
            argv += ["--connect-timeout", repr(float(self.connect_timeout_s))]
        if self.scouting_delay_s is not None:
            argv += ["--scouting-delay", repr(float(self.scouting_delay_s))]
        if self.config_file is not None:
            argv += ["--zenoh-config", self.config_file]
        return argv


RUNTIME_ENV = "ZENOH_RUNTIME"
#: ``ZENOH_RUNTIME`` values of :func:`use_zenoh_threads` (see the module docstring).
RUNTIME_PROFILES = {
    "agent": "(rx: (handover: app), tx: (handover: app), acc: (handover: app), "
             "net: (handover: app))",
    "relay": "(rx: (handover: app), acc: (handover: app), net: (handover: app))",
}


def use_zenoh_threads(profile: str) -> bool:
    """Set this process's (and its future children's) Zenoh thread profile (``"agent"`` or
    ``"relay"``, see the module docstring), unless ``ZENOH_RUNTIME`` holds a value of the
    user's own. Call it before the process's first ``zenoh.open``. True if it set it."""
    value = RUNTIME_PROFILES[profile]
    current = os.environ.get(RUNTIME_ENV)
    if current and current not in RUNTIME_PROFILES.values():
        return False
    os.environ[RUNTIME_ENV] = value
    return True


def _insert(conf: zenoh.Config, key: str, value: object, name: str) -> None:
    try:
        conf.insert_json5(key, json.dumps(value))
    except Exception as exc:  # noqa: BLE001 - zenoh.ZError
        raise ValueError(f"{name} {value!r} rejected by zenoh ({key}): {exc}") from None


def make_config(
    mode: Mode = "peer",
    connect: Sequence[str] = (),
    listen: Sequence[str] = (),
    multicast_scouting: bool = False,
    *,
    connect_timeout_s: float | None = None,
    scouting_delay_s: float | None = None,
    config_file: str | None = None,
    auth: UsrPwdAuth | None = None,
) -> zenoh.Config:
    """Build a ``zenoh.Config`` from typed arguments (see :class:`ZenohSettings`)."""
    return ZenohSettings(
        mode=mode,
        connect=tuple(connect),
        listen=tuple(listen),
        multicast_scouting=multicast_scouting,
        connect_timeout_s=connect_timeout_s,
        scouting_delay_s=scouting_delay_s,
        config_file=config_file,
        auth=auth,
    ).to_config()


def add_zenoh_args(parser: argparse.ArgumentParser) -> None:
    """Add the shared Zenoh flags to ``parser``, in an argument group ``zenoh``.

    Destinations are prefixed ``zenoh_`` so they never clash with a program's own options;
    ``--key-prefix`` (destination ``key_prefix``) is the key-space prefix of :mod:`wire.keys`.
    """
    group = parser.add_argument_group("zenoh")
    group.add_argument(
        "--mode", dest="zenoh_mode", choices=MODES, default="peer",
        help="zenoh session mode (default: peer)",
    )
    group.add_argument(
        "--connect", dest="zenoh_connect", metavar="ENDPOINT", action="append", default=[],
        help="endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable)",
    )
    group.add_argument(
        "--listen", dest="zenoh_listen", metavar="ENDPOINT", action="append", default=[],
        help="endpoint to listen on, e.g. tcp/0.0.0.0:7447 (repeatable)",
    )
    group.add_argument(
        "--multicast-scouting", dest="zenoh_multicast_scouting",
        action=argparse.BooleanOptionalAction, default=False,
        help="discover peers and routers by UDP multicast (default: off)",
    )
    group.add_argument(
        "--connect-timeout", dest="zenoh_connect_timeout", metavar="SECONDS", type=float,
        default=None, help="keep retrying the connect endpoints this long when opening",
    )
    group.add_argument(
        "--scouting-delay", dest="zenoh_scouting_delay", metavar="SECONDS", type=float,
        default=None, help="how long opening a peer or router waits for scouting",
    )
    group.add_argument(
        "--zenoh-config", dest="zenoh_config", metavar="FILE", default=None,
        help="a zenoh JSON5 configuration file to start from",
    )
    group.add_argument(
        "--auth", dest="zenoh_auth_file", metavar="FILE", default=None,
        help="log in with the user/password of this Zenoh JSON5 file (e.g. formation run's "
             "OUT/secure/manager.json5 or viewer.json5); its endpoints unless --connect",
    )
    group.add_argument(
        "--key-prefix", dest="key_prefix", metavar="PREFIX", default=keys.DEFAULT_PREFIX,
        help=f"key-space prefix (default: {keys.DEFAULT_PREFIX})",
    )


def settings_from_args(ns: argparse.Namespace) -> ZenohSettings:
    """The :class:`ZenohSettings` of a namespace parsed with :func:`add_zenoh_args`.

    With ``--auth FILE`` the user and password come from that file (:func:`read_auth_file`),
    and so do the endpoints when no ``--connect`` is given; the mode is then ``client``."""
    auth = None
    connect = tuple(ns.zenoh_connect)
    mode = ns.zenoh_mode
    auth_file = getattr(ns, "zenoh_auth_file", None)
    if auth_file is not None:
        found = read_auth_file(auth_file)
        auth = found.auth
        connect = connect or found.connect
        if mode == "peer" and not ns.zenoh_listen:
            mode = "client"  # credentials are for a router: talk to it, not to peers
    return ZenohSettings(
        mode=mode,
        connect=connect,
        listen=tuple(ns.zenoh_listen),
        multicast_scouting=ns.zenoh_multicast_scouting,
        connect_timeout_s=ns.zenoh_connect_timeout,
        scouting_delay_s=ns.zenoh_scouting_delay,
        config_file=ns.zenoh_config,
        auth=auth,
    )


@dataclass(frozen=True, slots=True)
class AuthFile:
    """What a credentials file (``secure/manager.json5`` and the like) holds."""

    path: str
    auth: UsrPwdAuth
    connect: tuple[str, ...]  # the router's endpoints, if the file names them


def client_auth_config(auth: UsrPwdAuth, connect: Sequence[str]) -> dict:
    """A client's Zenoh configuration fragment: the router's endpoints, no multicast scouting,
    and the user/password (as ``formation run`` writes ``secure/manager.json5``); plain JSON,
    which is JSON5."""
    return {
        "mode": "client",
        "connect": {"endpoints": list(connect)},
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"auth": {"usrpwd": {"user": auth.user, "password": auth.password}}},
    }


def read_auth_file(path: str | os.PathLike[str]) -> AuthFile:
    """The user, password and endpoints of a Zenoh JSON5 configuration (fragment) with
    ``transport/auth/usrpwd`` (parsed by zenoh itself, so comments and every JSON5 form zenoh
    takes are accepted), or of a one-line ``user:password`` file (``*.credentials``);
    ValueError naming the file and what is wrong with it."""
    name = os.fspath(path)
    if not os.path.isfile(name):
        raise ValueError(f"--auth: no such file {name!r}")
    try:
        with open(name, encoding="utf-8") as fh:
            head = fh.read(4096)
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"--auth {name}: cannot read: {exc}") from None
    line = head.strip()
    if line and "\n" not in line and not line.startswith(("{", "/")):  # user:password, one line
        user, sep, password = line.partition(":")
        if not (sep and user and password):
            raise ValueError(f"--auth {name}: expected user:password or a Zenoh JSON5 file")
        return AuthFile(name, UsrPwdAuth(user, password), ())
    try:
        conf = zenoh.Config.from_file(name)
    except Exception as exc:  # noqa: BLE001 - zenoh.ZError: not JSON5, an unknown key
        raise ValueError(f"--auth {name}: not a Zenoh configuration: {exc}") from None

    def get(key: str) -> object:
        try:
            return json.loads(conf.get_json(key))
        except Exception:  # noqa: BLE001 - zenoh.ZError: no such key
            return None

    found_user = get("transport/auth/usrpwd/user")
    found_password = get("transport/auth/usrpwd/password")
    if not (isinstance(found_user, str) and found_user and isinstance(found_password, str)
            and found_password):
        raise ValueError(f"--auth {name}: no transport/auth/usrpwd user and password in it")
    endpoints = get("connect/endpoints")
    connect = tuple(e for e in endpoints if isinstance(e, str)) if isinstance(endpoints, list) else ()
    return AuthFile(name, UsrPwdAuth(found_user, found_password), connect)


def open_session(settings: ZenohSettings, what: str = "zenoh") -> zenoh.Session:
    """``zenoh.open`` with a message that says why it failed (:func:`explain_open_failure`)
    as a ``ConnectionError``."""
    try:
        return zenoh.open(settings.to_config())
    except ValueError:
        raise
    except Exception as exc:  # noqa: BLE001 - zenoh.ZError says only "Timeout!" for most causes
        why = explain_open_failure(exc, settings.connect, settings.auth)
        raise ConnectionError(f"{what}: {why}" if what else why) from None


def explain_open_failure(exc: BaseException, connect: Sequence[str],
                         auth: UsrPwdAuth | None) -> str:
    """Why opening a client session failed, in words: zenoh reports refused credentials and an
    absent router alike (``Timeout!``), so look whether something listens on the endpoints."""
    reachable = [e for e in connect if _tcp_reachable(e)]
    said = zenoh_words(exc)
    if connect and not reachable:
        return f"no router answers on {', '.join(connect)} ({said})"
    if auth is not None and reachable:
        return (f"the router at {reachable[0]} refused the credentials of user {auth.user!r} "
                f"(wrong user or password, or not this router's credentials)")
    if reachable:
        return (f"{reachable[0]} accepts connections but no Zenoh session opened: a router that "
                f"wants credentials (--auth FILE)? ({said})")
    return said


def zenoh_words(exc: BaseException) -> str:
    """Zenoh's error message on one line, without the place in zenoh's Rust sources it names
    (``Unable to connect to any of [...]!  at /root/.cargo/.../orchestrator.rs:447.``)."""
    text = " ".join(str(exc).split())
    cut = text.find(" at /")
    return (text[:cut] if cut > 0 else text).rstrip(" .") or type(exc).__name__


def _tcp_reachable(endpoint: str, timeout_s: float = 1.0) -> bool:
    proto, _, address = endpoint.partition("/")
    if proto not in ("tcp", "tls") or ":" not in address:
        return False
    host, _, port = address.split("#", 1)[0].rpartition(":")
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=timeout_s):
            return True
    except (OSError, ValueError):
        return False


def config_from_args(ns: argparse.Namespace) -> zenoh.Config:
    """The ``zenoh.Config`` of a namespace parsed with :func:`add_zenoh_args`."""
    return settings_from_args(ns).to_config()
