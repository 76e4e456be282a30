"""``privslam serve --store DIR [--listen HOST:PORT] [--tls-cert PEM --tls-key PEM] [--token-file FILE]``.

The edge server (docs/edge.md, :mod:`privslam_jax.edge.server`): runs SLAM for every client
session and streams back a pose per frame and, on request, the map as a line cloud.  Sessions are
stored in ``--store`` as they grow; a restarted server resumes them.  Without ``--tls-cert`` the
port is plain HTTP/2: use that on loopback only.  Without ``--token-file`` no client is
authenticated.  Runs until interrupted (Ctrl-C or SIGTERM); refusals are logged on stderr.
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
from pathlib import Path

from privslam_jax.argtypes import positive_int

__all__ = ["add_parser", "run"]


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("serve", help="edge server: SLAM sessions over gRPC (docs/edge.md)",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--store", type=Path, required=True, help="folder of the sessions (created if absent)")
    p.add_argument("--listen", default="127.0.0.1:50051", help="HOST:PORT to listen on (default 127.0.0.1:50051)")
    p.add_argument("--tls-cert", type=Path, default=None, help="server certificate chain, PEM (with --tls-key)")
    p.add_argument("--tls-key", type=Path, default=None, help="server private key, PEM")
    p.add_argument("--token-file", type=Path, default=None,
                   help="bearer tokens, one per line ('token' or 'name token'); edit it to revoke one")
    p.add_argument("--max-sessions", type=positive_int, default=8, help="sessions served at once (default 8)")
    p.add_argument("--max-message-mb", type=positive_int, default=16, help="largest message in MB (default 16)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from privslam_jax.edge.server import start_server

    if (args.tls_cert is None) != (args.tls_key is None):
        raise ValueError("--tls-cert and --tls-key go together")
    for flag, path in (("--tls-cert", args.tls_cert), ("--tls-key", args.tls_key), ("--token-file", args.token_file)):
        if path is not None and not path.is_file():
            raise FileNotFoundError(f"{flag} {path}: no such file")
    tls = None if args.tls_cert is None else (args.tls_cert.read_bytes(), args.tls_key.read_bytes())
    host = args.listen.rsplit(":", 1)[0]
    if tls is None and host not in ("127.0.0.1", "localhost", "[::1]"):
        print(f"privslam serve: WARNING: no TLS on {args.listen}: frames, tokens and maps cross the network in clear",
              file=sys.stderr)
    log = logging.getLogger("privslam_jax.edge")
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(message)s"))
    log.addHandler(handler)
    log.setLevel(logging.INFO)
    server = start_server(args.store, args.listen, tls=tls, tokens=args.token_file,
                                max_sessions=args.max_sessions, max_message_bytes=args.max_message_mb * 1024 * 1024)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    print(f"privslam serve: listening on {host}:{server.port} ({'TLS' if tls else 'no TLS'}), store {args.store}", flush=True)
    stop.wait()
    server.stop(grace=5)
    print("privslam serve: stopped", flush=True)
    return 0
