"""Physical models, one module per published model."""
