"""What every part of mata-eval shares and no plugin needs to know about the rest: the value
types, plugin parameters, hooks and registry, the block interfaces, errors, the sequence and the
metric profiles."""
