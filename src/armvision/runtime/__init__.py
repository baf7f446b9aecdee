"""The running system: threads, state snapshots, the task worker (see system.py)."""
