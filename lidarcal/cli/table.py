"""``lidarcal table CERT.nc [--format csv|md|html] [-o FILE]``: the certificate's result table.

Given an ``smc`` artefact (``lidarcal smc``) instead, the campaign's per-bin table
(:func:`lidarcal.smc.binned_table`): one row per height and wind-speed bin holding campaign
periods, with the combined standard uncertainty, both routes and every contributor.

One row per height and wind-speed bin: the k = 2 expanded uncertainty in m/s and in % of the
bin's mean reference wind speed with the Monte Carlo's numerical tolerance beside it (JCGM 101
7.9), the Monte Carlo distribution of the error (estimate, standard uncertainty, 95 % coverage
interval, each with its tolerance) and what a certified bin certifies (±U, or the interval
where the two differ materially), the largest standard-uncertainty contributors, the number of
Monte Carlo trials and of distinct 10-minute periods in the bin and whether the bin is
certified (centre in the certified range, by default 4 to 16 m/s, at least ``min_periods``
periods, by default 10, and its Monte Carlo values settled) or why not, then the sensitivities
that are significant by Eq. 12 or Eq. 13 at that height.  The headline range quoted above the
table covers the settled certified bins only; the bins that did not settle are listed apart.
CSV (the default) carries every column with the certificate's unrounded values; Markdown and
HTML round for reading and list the sensitivities once per height.  Without ``-o`` the table
goes to stdout.

The certificate's seal is checked first (as ``lidarcal verify`` does): the numbers of an
altered, unsealed or wrongly signed certificate are not shown (exit status 2), unless
``--allow-invalid`` is given, which shows them under a warning banner (on stderr, and as the
first line of the table: a ``#`` comment in CSV).
"""

from __future__ import annotations

import argparse
import html
import sys
from pathlib import Path

from lidarcal.certificate import result_table
from lidarcal.certificate.admin import status_line
from lidarcal.certificate.seal import invalid_seal_banner, require_valid_seal
from lidarcal.cli import COMMANDS
from lidarcal.cli.options import add_overwrite_option
from lidarcal.io import atomic_path, check_writable, open_artefact
from lidarcal.readback import read_attr

FORMATS = ("csv", "md", "html")
_SUFFIXES = {".csv": "csv", ".md": "md", ".markdown": "md", ".html": "html", ".htm": "html"}


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``table`` subcommand."""
    p = sub.add_parser("table", help=COMMANDS["table"].help,
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("certificate", metavar="CERT.nc")
    p.add_argument("--format", choices=FORMATS,
                   help="output format (default: from the -o suffix, else csv)")
    p.add_argument("-o", "--output", metavar="FILE", help="write here instead of stdout")
    p.add_argument("--contributors", type=int, default=3, metavar="N",
                   help="contributors listed per bin, largest first (default %(default)s)")
    p.add_argument("--allow-invalid", action="store_true",
                   help="show the table even if the certificate's seal does not match its contents, "
                   "under a warning banner (by default such a certificate is refused)")
    add_overwrite_option(p)
    p.set_defaults(handler=run)


def _rounded(table):
    k = table.attrs["coverage_factor"]
    out = table.drop(columns=["significant_sensitivities", "wind_speed_min_m_s", "wind_speed_max_m_s"])
    return out.rename(columns={
        "height_m": "height (m)",
        "wind_speed_m_s": "wind speed (m/s)",
        "sample_count": "trials",
        "period_count": "periods",
        "bin_flag": "flag",
        "certified": "certified",
        "not_certified_reason": "not certified because",
        f"expanded_uncertainty_k{k:g}_m_s": f"U (k = {k:g}) (m/s)",
        f"expanded_uncertainty_k{k:g}_pct": f"U (k = {k:g}) (%)",
        "numerical_tolerance_pct": "± numerical tolerance (%)",
        "numerically_settled": "settled",
        "certified_statement": "certifies",
        "mean_difference_pct": "estimate (%)",
        "standard_uncertainty_pct": "u (%)",
        "coverage_interval_lower_pct": "95 % interval low (%)",
        "coverage_interval_upper_pct": "95 % interval high (%)",
        "expanded_uncertainty_coverage_pct": "coverage of ±U (%)",
        "effective_degrees_of_freedom": "ν_eff",
        "main_contributors": "main contributors (standard uncertainty, %)",
    }).drop(columns=[c for c in table.columns if c.startswith("tolerance_")]).round(
        {f"U (k = {k:g}) (m/s)": 3, f"U (k = {k:g}) (%)": 2, "estimate (%)": 2, "u (%)": 2,
         "95 % interval low (%)": 2, "95 % interval high (%)": 2, "coverage of ±U (%)": 1, "ν_eff": 0})


def _sensitivities(table) -> list[tuple[float, str]]:
    per = table.drop_duplicates("height_m")
    return [(z, s) for z, s in zip(per["height_m"], per["significant_sensitivities"], strict=True)]


def _cell(value) -> str:
    return "" if isinstance(value, float) and value != value else str(value)


def _markdown(table) -> str:
    body = _rounded(table)
    lines = [f"# Result table: {table.attrs.get('title', 'calibration certificate')}", "",
             *([f"**{table.attrs['status']}**", ""] if table.attrs.get("status") else []),
             table.attrs["headline"], "",
             "| " + " | ".join(body.columns) + " |", "|" + "---|" * len(body.columns)]
    lines += ["| " + " | ".join(_cell(v) for v in row) + " |" for row in body.itertuples(index=False)]
    if missed := table.attrs["not_settled_items"]:
        lines += ["", "## Not certified: Monte Carlo values not settled (JCGM 101 7.9)", ""]
        lines += [f"- {line}" for line in missed]
    lines += ["", "## Significant sensitivities (Eqs. 12-13)", ""]
    lines += [f"- {z:g} m: {s or 'none'}" for z, s in _sensitivities(table)]
    return "\n".join(lines) + "\n"


def _html(table) -> str:
    title = html.escape(f"Result table: {table.attrs.get('title', 'calibration certificate')}")
    sens = "".join(f"<li>{z:g} m: {html.escape(s or 'none')}</li>" for z, s in _sensitivities(table))
    grid = _rounded(table).to_html(index=False, na_rep="", border=0)
    status = table.attrs.get("status")
    status = f"<p><strong>{html.escape(status)}</strong></p>\n" if status else ""
    missed = "".join(f"<li>{html.escape(line)}</li>" for line in table.attrs["not_settled_items"])
    if missed:
        grid += ("\n<h2>Not certified: Monte Carlo values not settled (JCGM 101 7.9)</h2>\n"
                 f"<ul>{missed}</ul>")
    return (f"<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>{title}</title></head><body>\n"
            f"<h1>{title}</h1>\n{status}<p>{html.escape(table.attrs['headline'])}</p>\n{grid}\n"
            f"<h2>Significant sensitivities (Eqs. 12-13)</h2>\n<ul>{sens}</ul>\n</body></html>\n")


def render(table, fmt: str, *, banner: str | None = None) -> str:
    """Return ``table`` (from :func:`lidarcal.certificate.result_table`) as csv, md or html text.

    ``banner`` (a certificate whose seal does not hold) goes first: a ``#`` line in CSV, a
    bold paragraph in Markdown and HTML.
    """
    if fmt == "csv":
        head = f"# {banner}\n" if banner else ""
        return head + table.to_csv(index=False, lineterminator="\n")
    if fmt == "md":
        return (f"**{banner}**\n\n" if banner else "") + _markdown(table)
    page = _html(table)
    if banner:
        warning = f'<p class="invalid"><strong>{html.escape(banner)}</strong></p>\n'
        page = page.replace("<body>\n", "<body>\n" + warning, 1)
    return page


def _smc_text(ds, fmt: str) -> str:
    """Return the per-bin table of an ``smc`` artefact as csv, md or html (the status first)."""
    from lidarcal.smc import binned_table  # deferred: only for smc artefacts

    table = binned_table(ds)
    status = ("DEMONSTRATION result (from a demonstration certificate)" if table.attrs["demonstration"]
              else f"certificate status: {table.attrs['status']}")
    head = f"{table.attrs['title']}. {status}; environmental route quoted: {table.attrs['route']}"
    if fmt == "csv":
        return f"# {head}\n" + table.to_csv(index=False, lineterminator="\n")
    if fmt == "md":
        cells = table.round(4)
        lines = [f"**{head}**", "", "| " + " | ".join(cells.columns) + " |",
                 "|" + "---|" * len(cells.columns)]
        lines += ["| " + " | ".join(_cell(v) for v in row) + " |" for row in cells.itertuples(index=False)]
        return "\n".join(lines) + "\n"
    grid = table.round(4).to_html(index=False, na_rep="", border=0)
    return (f"<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>{html.escape(head)}</title></head>"
            f"<body>\n<p><strong>{html.escape(head)}</strong></p>\n{grid}\n</body></html>\n")


def run(args: argparse.Namespace) -> int:
    """Build the table and write it."""
    fmt = args.format or (_SUFFIXES.get(Path(args.output).suffix.lower(), "csv") if args.output else "csv")
    if args.output:
        check_writable(args.output, overwrite=args.overwrite)
    found = open_artefact(args.certificate)
    if read_attr(found, "lidarcal_artefact") == "smc":
        text = _smc_text(found, fmt)
        if not args.output:
            sys.stdout.write(text)
            return 0
        with atomic_path(args.output, overwrite=args.overwrite) as tmp:
            Path(tmp).write_text(text, encoding="utf-8")
        print(f"{args.output}: {text.splitlines()[0].lstrip('#* ')}")
        return 0
    cert = open_artefact(args.certificate, "certificate")
    seal = require_valid_seal(args.certificate, allow_invalid=args.allow_invalid)
    banner = invalid_seal_banner(seal) if seal is not None and not seal.ok else None
    if banner:
        print(f"lidarcal table: {banner}", file=sys.stderr)
    table = result_table(cert, contributors=args.contributors, allow_invalid=True)  # checked just above
    table.attrs["title"] = cert.attrs.get("title", "calibration certificate")
    table.attrs["status"] = status_line(cert.attrs)
    text = render(table, fmt, banner=banner)
    if not args.output:
        if fmt == "csv":  # the CSV stays a plain table: the status goes first on stderr
            print(f"{args.certificate}: {table.attrs['status']}", file=sys.stderr)
        sys.stdout.write(text)
        return 0
    print(f"{args.output}: {table.attrs['status']}")
    with atomic_path(args.output, overwrite=args.overwrite) as tmp:
        Path(tmp).write_text(text, encoding="utf-8")
    print(f"{args.output}: {len(table)} bins; {table.attrs['headline']}")
    return 0
