"""Check a compose document against the two Compose schemas users' tools apply, without a Docker engine.

* ``compose-spec``: the Compose Specification's JSON Schema (what Docker Compose v2, ``docker compose``,
  validates against), JSON Schema draft 2020-12.
* ``docker-compose-1.29.2``: the schema Debian 12's ``docker-compose`` 1.29.2 applies to every file that is
  not file format 1 (since 1.27 it validates ``version: "2.x"``, ``"3.x"`` and version-less files alike
  against its own copy of the Compose Specification, from early 2021). It is checked the way that tool
  does (``compose/config/validation.py``): ``Draft4Validator`` over the whole file, then each service
  against ``definitions.constraints.service`` (an ``image`` or a ``build``). Its custom formats (``ports``,
  ``expose``, ``subnet_ip_address``) are not re-implemented: ``docker-compose config`` checks those where
  it is installed (tests/deploy/test_compose.py).

Both schema files are vendored in ``deploy/schema/`` (sources, checksums and licence in its README.md);
nothing is downloaded. Needs the ``jsonschema`` library (the ``dev`` extra).
"""

from __future__ import annotations

import json
from functools import cache
from pathlib import Path
from typing import Any

SCHEMA_DIR = Path(__file__).resolve().parent / "schema"
COMPOSE_SPEC = "compose-spec"
DOCKER_COMPOSE_V1 = "docker-compose-1.29.2"
SCHEMAS = (COMPOSE_SPEC, DOCKER_COMPOSE_V1)
"""The schemas a generated compose file must satisfy, by their file name in ``deploy/schema/``."""


@cache
def load_schema(name: str) -> dict[str, Any]:
    """The vendored schema ``deploy/schema/{name}.json``."""
    if name not in SCHEMAS:
        raise ValueError(f"unknown compose schema {name!r}: choose one of {', '.join(SCHEMAS)}")
    return json.loads((SCHEMA_DIR / f"{name}.json").read_text(encoding="utf-8"))


def _where(error: Any) -> str:
    return "/".join(str(p) for p in error.absolute_path) or "(top level)"


def schema_errors(doc: dict[str, Any], name: str) -> list[str]:
    """Every violation of schema ``name`` by the compose document ``doc`` (a parsed YAML mapping), each as
    ``"path: message"``; empty when the document is valid."""
    try:
        import jsonschema
    except ImportError as exc:
        raise RuntimeError("checking a compose file needs the jsonschema library: "
                           "pip install -e '.[dev]' (or `make test`, which installs it)") from exc
    schema = load_schema(name)
    if name == COMPOSE_SPEC:
        validator = jsonschema.Draft202012Validator(schema)
        errors = [f"{_where(e)}: {e.message}" for e in validator.iter_errors(doc)]
    else:  # as docker-compose 1.29.2 does it: draft 4, then the per-service constraints
        errors = [f"{_where(e)}: {e.message}" for e in jsonschema.Draft4Validator(schema).iter_errors(doc)]
        constraints = jsonschema.Draft4Validator(schema["definitions"]["constraints"]["service"])
        services = doc.get("services") if isinstance(doc, dict) else None
        for service, config in (services.items() if isinstance(services, dict) else ()):
            errors += [f"services/{service}: {e.message}" for e in constraints.iter_errors(config)]
    return sorted(errors)


def compose_errors(doc: dict[str, Any]) -> dict[str, list[str]]:
    """Violations of ``doc`` per schema in ``SCHEMAS`` (only the schemas it violates)."""
    found = {name: schema_errors(doc, name) for name in SCHEMAS}
    return {name: errs for name, errs in found.items() if errs}
