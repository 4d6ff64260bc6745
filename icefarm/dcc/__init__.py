"""Helpers that run inside other applications (DCCs), not in icefarm's own processes."""
