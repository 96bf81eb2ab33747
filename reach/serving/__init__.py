"""Serving over ZeroMQ: the wire protocol and its table of operations, the broker (server), the workers and the
client."""
