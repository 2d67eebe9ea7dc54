"""Built-in scenario files (TOML), installed as package data so every process can load them by name."""
