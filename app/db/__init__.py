"""Database: SQLAlchemy 2 models and session factory (SQLite by default)."""
