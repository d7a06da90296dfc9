"""Measures of mouth shapes and lip sync (error vs tracked mouth, opening correlation, best lag)."""
