"""Built-in mata-eval plugins. Installed as the package `mata_eval_plugins`; the core never imports it."""
