"""Transfer experiments: tasks over option dynamics learned once (issue 32)."""
