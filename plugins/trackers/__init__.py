"""Built-in trackers plugins (registered through the `mata_eval` entry-point group)."""
