"""The strict reader of tofu's CSV files for the plot scripts (one place for all of them):
rows as tuples, each field converted by a parser whose docstring names the expected form;
a malformed row raises CsvError naming file:line and the column.

    from tofu_csv import CsvError, read_csv, timestamp, number, ...
"""
import math


class CsvError(Exception):
    """A malformed CSV row; the message names file and line."""


def read_csv(path, columns, parsers, last_field_may_hold_commas=False):
    """Rows of a tofu CSV as tuples, each field converted by its parser. Lines starting
    with '#' are headers or comments. With last_field_may_hold_commas the last column
    takes the rest of the line (free text). Raises CsvError naming file:line on a bad row."""
    rows = []
    with open(path, newline="", encoding="utf-8") as f:
        try:
            lines = f.readlines()
        except UnicodeDecodeError as e:
            raise CsvError(f"{path}: not UTF-8 text ({e.reason})") from None
    for line_number, line in enumerate(lines, start=1):
        line = line.rstrip("\r\n")
        if not line or line.startswith("#"):
            continue
        if last_field_may_hold_commas:
            fields = line.split(",", len(columns) - 1)
        else:
            fields = line.split(",")
        if len(fields) != len(columns):
            raise CsvError(f"{path}:{line_number}: expected {len(columns)} fields "
                           f"({','.join(columns)}), got {len(fields)}: '{line}'")
        row = []
        for column, parser, field in zip(columns, parsers, fields):
            try:
                row.append(parser(field))
            except ValueError:
                raise CsvError(f"{path}:{line_number}: column '{column}': expected "
                               f"{parser.__doc__}, got '{field}'") from None
        rows.append(tuple(row))
    return rows


def timestamp(text):
    """an integer timestamp in ns"""
    return int(text) * 1e-9


def number(text):
    """a finite number"""
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(text)
    return value


def optional_number(text):
    """a number or nothing"""
    return float(text) if text.strip() else float("nan")


def flag(text):
    """0 or 1"""
    if text not in ("0", "1"):
        raise ValueError(text)
    return text == "1"


def name(text):
    """a name"""
    if not text.strip():
        raise ValueError(text)
    return text


def any_text(text):
    """text"""
    return text
