"""The edge-assisted split (docs/edge.md): a device client and an edge SLAM server over gRPC.

* :mod:`.codec` — what crosses the wire and every check of it;
* :mod:`.session` — one SLAM session of the server, persisted and resumable;
* :mod:`.server` — the gRPC service: TLS, bearer tokens, limits, concurrent sessions;
* :mod:`.client` — the device side: filtered frames out, poses and a line-cloud map back.

``edge.proto`` is the protocol; ``edge_pb2*.py`` are generated from it (the command is in its header).
"""
