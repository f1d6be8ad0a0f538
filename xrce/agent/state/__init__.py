"""What a client told the agent, kept across the agent's restarts (issue 51): ``store`` (the
SQLite file), ``recorder`` (the engine's hooks into it, and the restore at start).
docs/RECOVERY.md says how boards behave across a restart."""
