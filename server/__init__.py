"""intspace service: the FastAPI app, its database, the live 3D scene and the command line."""
