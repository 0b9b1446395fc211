"""The ASAM schemas ``scenariogeneration`` ships (its wheel installs them beside the package, in
``site-packages/schemas``) and validation against them with lxml (xmlschema takes ~30 times as long
on a city's OpenDRIVE)."""
from __future__ import annotations

import functools
import os

OPENSCENARIO_XSD = "OpenSCENARIO_1_{minor}.xsd"
OPENDRIVE_XSD = "opendrive_{major}{minor}_core.xsd"


class SchemaMissing(LookupError):
    """No schema of that version is installed."""


def schema_dir() -> str:
    import scenariogeneration
    return os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(scenariogeneration.__file__))), "schemas")


def openscenario_xsd(minor: int) -> str:
    return _existing(OPENSCENARIO_XSD.format(minor=minor))


def opendrive_xsd(major: int, minor: int) -> str:
    return _existing(OPENDRIVE_XSD.format(major=major, minor=minor))


def installed_opendrive() -> list[str]:
    """The OpenDRIVE versions whose schema is installed, e.g. ``["1.7"]``."""
    names = [n for n in os.listdir(schema_dir()) if n.startswith("opendrive_") and n.endswith("_core.xsd")]
    return sorted(f"{n.split('_')[1][0]}.{n.split('_')[1][1:]}" for n in names)


def _existing(name: str) -> str:
    path = os.path.join(schema_dir(), name)
    if not os.path.isfile(path):
        raise SchemaMissing(f"{name}: not installed with scenariogeneration ({schema_dir()})")
    return path


@functools.lru_cache(maxsize=None)
def _schema(xsd: str):
    from lxml import etree
    return etree.XMLSchema(etree.parse(xsd))


def schema_errors(path: str, xsd: str, limit: int = 5) -> tuple[int, list[str]]:
    """(how many, the first ``limit`` as "line N: message") errors of ``path`` against ``xsd``."""
    from lxml import etree
    schema = _schema(xsd)
    schema.validate(etree.parse(path))
    errors = list(schema.error_log)
    return len(errors), [f"line {e.line}: {e.message}" for e in errors[:limit]]
