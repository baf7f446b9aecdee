"""Tasks the motion worker runs: grab, follow, analyze (each a function of a TaskContext)."""
