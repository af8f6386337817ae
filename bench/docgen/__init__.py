"""Generators of the regions that bench/regenerate_docs.py rewrites, one module per part of the docs."""
