"""Model types: the registry (``registry``) and one module per built-in type with its config,
network and backend. A new model is one module here or in any package (docs/design.md,
"Extending")."""
