"""Roadmap construction: node sampling and regions, edge design, connectivity."""
