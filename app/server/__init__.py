"""Server-side orchestration: node registry, clock estimation, recordings, node websocket."""
