"""Prompt templates, one set per robot role (package data)."""
