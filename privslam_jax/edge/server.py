"""The edge server: SLAM sessions over gRPC (``edge.proto``, docs/edge.md).

:func:`start_server` serves ``EdgeSlam.Session``: one bidirectional stream per session, several
sessions at once (each in its own thread of the server's pool, up to ``max_sessions``; more
are refused with ``RESOURCE_EXHAUSTED``).  Each session is an
:class:`~privslam_jax.edge.session.EdgeSession`, persisted in ``store`` as it grows, so a
restarted server resumes it.

Trust and limits:

* **TLS** when given a certificate and key (``grpc.ssl_server_credentials``); without, the port is
  plain HTTP/2 (for loopback).
* **Bearer tokens** (``authorization: Bearer <token>`` metadata) checked against a token file
  (:class:`TokenFile`; re-read when it changes, so deleting a line revokes that token at the next
  call) before any request is read; a refusal ends the call with ``UNAUTHENTICATED`` and is
  logged with the peer's address.
* **Sizes**: a message is at most ``max_message_bytes`` (gRPC refuses larger ones before they are
  read, ``RESOURCE_EXHAUSTED``); a session announces its image size, at most
  :data:`~privslam_jax.edge.codec.MAX_PIXELS`, and every PNG must match it before it is decoded.
* **Validation**: a bad calibration or frame (corrupt PNG, wrong size, NaN, a gap in the frame
  indices) ends that session's call with ``INVALID_ARGUMENT`` and a message naming the frame and
  the field; what was accepted before stays stored, and other sessions are not affected.

The client sets each call's deadline (:mod:`privslam_jax.edge.client`).

**CPU sharing.**  OpenCV's thread pool (ORB extraction, RANSAC) is process-wide: with one session
it keeps every core, with several it runs single-threaded, as the sessions already run side by
side and more threads only contend (``benchmarks/bench_edge.py`` measures the effect; docs/edge.md).
Results do not depend on it: the poses equal a single-process run's.
"""

from __future__ import annotations

import collections
import hmac
import logging
import threading
from concurrent import futures
from pathlib import Path
from typing import NamedTuple

import cv2
import grpc
import numpy as np

from privslam_jax.edge import edge_pb2 as pb
from privslam_jax.edge import edge_pb2_grpc as pb_grpc
from privslam_jax.edge.session import EdgeSession
from privslam_jax.errors import InputError

__all__ = ["TokenFile", "EdgeServicer", "EdgeServer", "start_server", "DEFAULT_MAX_MESSAGE_BYTES"]

log = logging.getLogger("privslam_jax.edge")

DEFAULT_MAX_MESSAGE_BYTES = 16 * 1024 * 1024
"""A 1226×370 grey PNG is about 0.3 MB; stereo doubles it."""


class TokenFile:
    """Bearer tokens, one per line (``token`` or ``name token``; ``#`` starts a comment), re-read
    whenever the file's modification time or size changes."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self._stamp: tuple[int, int] | None = None
        self._tokens: dict[str, str] = {}
        self._lock = threading.Lock()
        self._load()
        if not self._tokens:
            raise InputError(f"{self.path}: no token in the token file")

    def _load(self) -> None:
        st = self.path.stat()
        stamp = (st.st_mtime_ns, st.st_size)
        if stamp == self._stamp:
            return
        tokens = {}
        for n, line in enumerate(self.path.read_text().splitlines(), 1):
            parts = line.split("#", 1)[0].split()
            if not parts:
                continue
            if len(parts) > 2:
                raise InputError(f"{self.path}:{n}: expected 'token' or 'name token'")
            tokens[parts[-1]] = parts[0] if len(parts) == 2 else f"token on line {n}"
        self._tokens, self._stamp = tokens, stamp

    def check(self, header: str) -> str | None:
        """The name of the token in an ``authorization`` header value, or ``None`` if it is none of them."""
        if not header.startswith("Bearer "):
            return None
        given = header[len("Bearer "):].encode()
        with self._lock:
            try:
                self._load()
            except (OSError, InputError) as err:  # an unreadable token file refuses everyone
                log.error("token file %s unreadable: %s", self.path, err)
                return None
            found = None
            for token, name in self._tokens.items():  # compare with every token, in constant time each
                if hmac.compare_digest(given, token.encode()):
                    found = name
            return found


class _BearerAuth(grpc.ServerInterceptor):
    def __init__(self, tokens: TokenFile):
        self.tokens = tokens

    def intercept_service(self, continuation, details):
        header = dict(details.invocation_metadata or ()).get("authorization", "")
        name = self.tokens.check(header)
        if name is not None:
            return continuation(details)
        reason = "no bearer token" if not header else "unknown or revoked bearer token"

        def refuse(request_iterator, context):
            log.warning("refused %s from %s: %s", details.method, context.peer(), reason)
            context.abort(grpc.StatusCode.UNAUTHENTICATED, reason)

        return grpc.stream_stream_rpc_method_handler(refuse)


class EdgeServicer(pb_grpc.EdgeSlamServicer):
    """``EdgeSlam.Session`` over the sessions of ``store``."""

    def __init__(self, store: str | Path, persist_every: int = 10, keep_idle: int = 4):
        self.store = Path(store)
        self.store.mkdir(parents=True, exist_ok=True)
        self.persist_every = persist_every
        self.keep_idle = keep_idle
        self._sessions: collections.OrderedDict[str, EdgeSession] = collections.OrderedDict()
        self._lock = threading.Lock()
        self._active = 0
        self._opencv_threads = cv2.getNumThreads()

    def _count(self, delta: int) -> None:
        """Sessions being served: OpenCV keeps its threads for one, runs single-threaded for several."""
        with self._lock:
            self._active += delta
            cv2.setNumThreads(self._opencv_threads if self._active <= 1 else 1)

    def _open(self, cal: pb.Calibration) -> EdgeSession:
        with self._lock:
            session = self._sessions.get(cal.session_id)
            if session is not None and session.calibration != cal:
                session = None  # EdgeSession.open compares with the store and refuses
            if session is None:
                session = EdgeSession.open(self.store, cal, self.persist_every)
                self._sessions[cal.session_id] = session
            self._sessions.move_to_end(cal.session_id)
            return session

    def _release(self, session: EdgeSession) -> None:
        session.lock.release()
        with self._lock:  # keep the last few idle sessions in memory (a reconnect then skips the replay)
            idle = [k for k, s in self._sessions.items() if not s.lock.locked()]
            for k in idle[: max(0, len(idle) - self.keep_idle)]:
                del self._sessions[k]

    def result(self, session_id: str):
        """The :class:`~privslam_jax.slam.system.SlamResult` of a session this server holds in memory
        (for evaluation next to the server, e.g. ``privslam run --edge``; it never crosses the wire)."""
        with self._lock:
            session = self._sessions.get(session_id)
        if session is None:
            raise KeyError(f"session {session_id} is not in memory")
        with session.lock:
            return session.slam.result(np.asarray(session.timestamps))

    def Session(self, request_iterator, context):  # noqa: N802 (the gRPC method's name)
        session = None
        try:
            first = next(request_iterator, None)
            if first is None or first.WhichOneof("kind") != "calibration":
                raise InputError("the first message of a session must be its calibration")
            session = self._open(first.calibration)
            if not session.lock.acquire(blocking=False):
                sid, session = first.calibration.session_id, None
                context.abort(grpc.StatusCode.ABORTED, f"session {sid} is served on another connection")
            self._count(+1)
            log.info("session %s (%s) from %s: %d frames stored", session.calibration.session_id, session.mode,
                     context.peer(), session.next_index)
            yield pb.Down(started=pb.Started(session_id=session.calibration.session_id, next_index=session.next_index))
            for msg in request_iterator:
                kind = msg.WhichOneof("kind")
                if kind == "frame":
                    yield pb.Down(pose=session.accept(msg.frame))
                    session.after_reply()  # local mapping while the next frame is on its way
                elif kind == "trajectory_request":
                    session.persist()
                    yield pb.Down(trajectory=session.trajectory())
                elif kind == "map_request":
                    yield pb.Down(line_cloud=session.line_cloud())
                else:
                    raise InputError(f"unexpected {kind or 'empty'} message after the calibration")
        except InputError as err:
            log.warning("session %s from %s: refused: %s", first.calibration.session_id if first else "?",
                        context.peer(), err)
            context.abort(grpc.StatusCode.INVALID_ARGUMENT, str(err))
        finally:
            if session is not None:
                try:
                    session.persist()
                finally:
                    self._count(-1)
                    self._release(session)


class EdgeServer(NamedTuple):
    """A running server (:func:`start_server`)."""

    server: grpc.Server
    port: int
    """The port it listens on."""
    servicer: EdgeServicer

    def stop(self, grace: float | None = None) -> None:
        """Stop serving (``grace`` seconds for the calls in progress; ``None``: none) and wait until stopped."""
        self.server.stop(grace).wait()


def start_server(store: str | Path, listen: str = "127.0.0.1:0", *, tls: tuple[bytes, bytes] | None = None,
                 tokens: str | Path | None = None, max_sessions: int = 8,
                 max_message_bytes: int = DEFAULT_MAX_MESSAGE_BYTES, persist_every: int = 10) -> EdgeServer:
    """Start serving; returns the :class:`EdgeServer` (``listen`` may ask for port 0: any free one).

    ``tls``: ``(certificate chain PEM, private key PEM)``; ``tokens``: a token file (:class:`TokenFile`;
    ``None``: no authentication).
    """
    interceptors = [_BearerAuth(TokenFile(tokens))] if tokens is not None else []
    options = [("grpc.max_receive_message_length", max_message_bytes),
               ("grpc.max_send_message_length", max_message_bytes)]
    server = grpc.server(futures.ThreadPoolExecutor(max_workers=max_sessions, thread_name_prefix="edge-session"),
                         interceptors=interceptors, options=options, maximum_concurrent_rpcs=max_sessions)
    servicer = EdgeServicer(store, persist_every=persist_every)
    pb_grpc.add_EdgeSlamServicer_to_server(servicer, server)
    if tls is not None:
        port = server.add_secure_port(listen, grpc.ssl_server_credentials([(tls[1], tls[0])]))
    else:
        port = server.add_insecure_port(listen)
    if port == 0:
        raise OSError(f"could not listen on {listen}")
    server.start()
    log.info("serving EdgeSlam on %s (port %d, %s, %s)", listen, port, "TLS" if tls else "no TLS",
             "bearer tokens" if tokens else "no authentication")
    return EdgeServer(server, port, servicer)
