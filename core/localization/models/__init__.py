"""Model files installed with the project (package data): see README.md beside this file."""
