"""Prefect flows: thin wrappers that wire dynplan's library functions into tasks.

Defaults set here before Prefect is imported: no usage telemetry (nothing leaves the host, and on a closed network
the ephemeral API's SQLite database is locked by the heartbeat when it cannot send), and a longer wait for the
ephemeral API to start (Prefect's 20 s is too short on a busy host with few cores, e.g. beside a training run).
"""

import os

from dynplan.interrupts import interrupt_while_loading

interrupt_while_loading()

os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
os.environ.setdefault("PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS", "120")
