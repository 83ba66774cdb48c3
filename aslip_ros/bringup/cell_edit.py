"""Write measured values into a lab's cell file, keeping the rest of it as the lab wrote it.

A YAML round trip would drop the file's comments (the cell file is the lab's notebook:
config/cell_example.yaml explains every key in them); instead each ``key: value`` line of a
section is replaced in place (its trailing comment kept), or added at the top of its
section, or the section is appended. The result is parsed again and must equal the file's
content with exactly those values changed, else nothing is written; the file is replaced
atomically (:func:`aslip_ros.util.write_text`).
"""

from __future__ import annotations

import copy
import re
from pathlib import Path
from typing import Any, Dict

import yaml

from aslip_ros.cell import CellError, load_cell
from aslip_ros.util import write_text


def _flow(value: Any) -> str:
    if isinstance(value, (list, tuple)):
        return '[' + ', '.join(_flow(v) for v in value) + ']'
    if isinstance(value, float):
        text = f'{value:.6f}'.rstrip('0') if abs(value) < 1e6 else repr(value)
        return text + '0' if text.endswith('.') else text
    return yaml.safe_dump(value, default_flow_style=True).strip().removesuffix('...').strip()


def _set(lines: list, section: str, key: str, value: Any) -> list:
    head = next((i for i, line in enumerate(lines)
                 if re.match(rf'^{re.escape(section)}\s*:', line)), None)
    if head is None:
        return lines + [f'{section}:\n', f'  {key}: {_flow(value)}\n']
    inline = re.match(rf'^{re.escape(section)}\s*:\s*(\{{\s*\}})?\s*(#.*)?$', lines[head])
    if inline is None:
        raise CellError(f'section {section!r} is not a block mapping ({lines[head].strip()!r}): '
                        f'set {key} by hand')
    end = next((i for i in range(head + 1, len(lines))
                if lines[i].strip() and not lines[i].startswith((' ', '\t', '#'))), len(lines))
    body = [i for i in range(head + 1, end)
            if lines[i].strip() and not lines[i].lstrip().startswith('#')]
    indent = re.match(r'^(\s*)', lines[body[0]]).group(1) if body else '  '
    for i in body:
        m = re.match(rf'^(\s*){re.escape(key)}\s*:\s*(\[[^\]]*\]|[^#\s][^#]*?)?(\s*#.*)?$',
                     lines[i].rstrip('\n'))
        if m and m.group(1) == indent:
            if m.group(2) is None:
                raise CellError(f'{section}.{key} spans several lines: set it by hand')
            lines[i] = f'{indent}{key}: {_flow(value)}{m.group(3) or ""}\n'
            return lines
    if inline.group(1):                  # "section: {}": becomes a block
        lines[head] = f'{section}:{" " + inline.group(2) if inline.group(2) else ""}\n'
    return lines[:head + 1] + [f'{indent}{key}: {_flow(value)}\n'] + lines[head + 1:]


def set_cell_values(path: str | Path, values: Dict[str, Dict[str, Any]]) -> None:
    """Set ``values`` (``{section: {key: value}}``) in the cell file at ``path``.

    :raises CellError: the file is not a cell file, a key is written in a form this edit
        does not handle (several lines), or the edit would change anything else.
    """
    path = Path(path).expanduser()
    before = load_cell(str(path))
    lines = path.read_text().splitlines(keepends=True)
    if lines and not lines[-1].endswith('\n'):
        lines[-1] += '\n'
    for section, keys in values.items():
        for key, value in keys.items():
            lines = _set(lines, section, key, value)
    text = ''.join(lines)
    want = copy.deepcopy(before.sections)
    for section, keys in values.items():
        want.setdefault(section, {}).update(keys)
    try:
        got = yaml.safe_load(text) or {}
    except yaml.YAMLError as exc:
        raise CellError(f'cell file {path}: the edit would not parse ({exc}); nothing written')
    got = {k: (v or {}) for k, v in got.items()}
    if _rounded(got) != _rounded(want):
        raise CellError(f'cell file {path}: the edit would change more than '
                        f'{sorted(values)}; nothing written')
    write_text(path, text)


def _rounded(doc: Any) -> Any:
    if isinstance(doc, dict):
        return {k: _rounded(v) for k, v in doc.items()}
    if isinstance(doc, list):
        return [_rounded(v) for v in doc]
    if isinstance(doc, float):
        return round(doc, 6)
    return doc
