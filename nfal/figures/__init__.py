"""Figures a person looks at (matplotlib, Agg backend): one module per command group."""
