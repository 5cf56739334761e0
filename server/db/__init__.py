"""The registry's database: typed SQLAlchemy models, engine and session, Alembic migrations."""
