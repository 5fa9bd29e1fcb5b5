"""Prefect flows: thin wrappers that wire dynplan's library functions into tasks.

Defaults set here before Prefect is imported: no usage telemetry (this project runs on closed networks, and
the ephemeral API's SQLite database is locked by the heartbeat when it cannot send).
"""

import os

os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
