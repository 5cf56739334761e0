"""Pydantic request and response schemas of the API, separate from the ORM models."""
