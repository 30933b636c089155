"""Built-in dataset plugins. Each module is its own entry point in the ``mata_eval`` group (see
pyproject.toml), so a module that fails to import is reported and the others keep working."""
