"""How long a test waits for an event (a state, a message, a file) before it calls the
wait a hang (the suite holds on a loaded machine).

A test waits for the event itself, never for a fixed time or a count that depends on
speed; the deadline below only guards against a hang, so it is generous: a loaded
machine makes a test slower, never wrong. It stays well inside pytest's own timeout
(``timeout = 600`` in pyproject.toml), which bounds every test.
"""
from __future__ import annotations

#: seconds a wait for server-side work (a job, a page update, a child process) may take
#: before the test reports a hang
HANG_S = 300.0
