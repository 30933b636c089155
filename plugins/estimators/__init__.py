"""Built-in estimators plugins (registered through the `mata_eval` entry-point group)."""
