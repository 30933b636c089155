"""Built-in egomotion plugins (registered through the `mata_eval` entry-point group)."""
