"""The bench server: one process owns the bench, runs a persistent plan queue and serves
clients over HTTP and a WebSocket event stream (docs/decisions/0080-0086)."""
