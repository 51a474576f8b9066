"""Component options from the command line (``--model-opt key=value``) and run configurations (TOML)."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from vladrivebench.errors import ConfigError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


def parse_value(text: str) -> Any:
    """``"0.5"`` → 0.5, ``"true"`` → True, ``"[1, 2]"`` → [1, 2], anything else stays a string."""
    lowered = text.strip().lower()
    if lowered in {"true", "false"}:
        return lowered == "true"
    try:
        return json.loads(text)
    except ValueError:
        return text


def parse_options(pairs: tuple[str, ...] | list[str], flag: str) -> dict[str, Any]:
    """Parse repeated ``key=value`` arguments of ``flag`` into a dict."""
    options: dict[str, Any] = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"{flag} {pair!r}: expected key=value, e.g. {flag} alpha=0.5")
        options[key.strip().replace("-", "_")] = parse_value(value)
    return options


def load_toml(path: Path | str, what: str = "configuration file") -> dict[str, Any]:
    """Read a TOML file, turning every failure into one line naming the file."""
    path = Path(path)
    try:
        with path.open("rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError(f"{what} {path}: no such file") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{what} {path}: not valid TOML ({exc})") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{what} {path}: not UTF-8 text (byte {exc.start}); TOML files are UTF-8") from None
    except OSError as exc:
        raise ConfigError(f"{what} {path}: cannot read ({exc.strerror})") from None


def load_data_file(path: Path | str, what: str) -> dict[str, Any]:
    """Read a TOML or JSON mapping, one clear line on failure."""
    path = Path(path)
    if path.suffix.lower() == ".json":
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise ConfigError(f"{what} {path}: no such file") from None
        except UnicodeDecodeError as exc:
            raise ConfigError(f"{what} {path}: not UTF-8 text (byte {exc.start}); JSON files are UTF-8") from None
        except ValueError as exc:
            raise ConfigError(f"{what} {path}: not valid JSON ({exc})") from None
        except OSError as exc:
            raise ConfigError(f"{what} {path}: cannot read ({exc.strerror})") from None
        if not isinstance(data, dict):
            raise ConfigError(f"{what} {path}: expected a JSON object at the top level")
        return data
    return load_toml(path, what)
