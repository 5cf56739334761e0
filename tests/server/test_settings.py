"""Settings from the environment, printed with their secrets masked."""

from __future__ import annotations

from pathlib import Path

from server.settings import Settings


def test_environment_and_defaults(monkeypatch, tmp_path):
    for name in ("DATABASE_URL", "ADMIN_TOKEN", "PUBLIC_READS", "VISER_PORT"):
        monkeypatch.delenv(f"INTSPACE_{name}", raising=False)
    monkeypatch.setenv("INTSPACE_DATA_DIR", str(tmp_path))
    monkeypatch.setenv("INTSPACE_PUBLIC_READS", "true")
    settings = Settings(_env_file=None)
    assert settings.resolved_database_url == f"sqlite:///{tmp_path / 'intspace.sqlite3'}"
    assert settings.database_backend == "sqlite"
    assert settings.public_reads is True and settings.viser_port == 8080
    assert settings.simulation is False and settings.cors_origins == []
    assert Settings(_env_file=None, data_dir=Path("var")).data_dir == Path("var")


def test_masked_hides_token_and_database_password():
    settings = Settings(
        _env_file=None,
        database_url="postgresql+psycopg://intspace:s3cret@db:5432/intspace",
        admin_token="very-secret-token",
    )
    printed = repr(settings.masked())
    assert "s3cret" not in printed and "very-secret-token" not in printed
    assert "db:5432/intspace" in printed
    assert settings.database_backend == "postgresql"
