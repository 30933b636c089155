"""Built-in protocols plugins (registered through the `mata_eval` entry-point group)."""
