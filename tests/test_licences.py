"""Licences: every runtime dependency of freqbrdf is permissively licensed, and LICENSE / NOTICE
cover what the package itself ships.

The licences are read from the installed distributions' metadata (importlib.metadata):
License-Expression (an SPDX expression, PEP 639) where a distribution has one, otherwise its
"License ::" classifiers and a License field that names a licence. The dependencies walked are
the runtime requirements of freqbrdf (from the checkout's pyproject.toml, so that an editable
install with stale metadata does not matter; from the installed freqbrdf otherwise) and,
transitively, theirs, with environment markers evaluated and no extras (test, diffusion).
"""

from __future__ import annotations

import importlib.metadata as metadata
import re
from dataclasses import dataclass
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

# The licence families a runtime dependency may have: permissive licences, which ask a user who
# ships freqbrdf in a product only to keep copyright and licence notices (Apache-2.0 also
# grants patents and asks to keep NOTICE files). Each family: its SPDX identifiers, its
# "License ::" classifiers (the part after "License :: OSI Approved :: " or "License :: "), and
# the names a License field gives it.
#
# Not on the list, so a dependency under one fails the test:
# - GPL, LGPL, AGPL (strong or library copyleft) and non-commercial or proprietary licences;
# - MPL-2.0 (weak, file-level copyleft), by decision: it would let freqbrdf be used unmodified,
#   but whoever ships an MPL-covered file must offer that file's source under the MPL, an
#   obligation beyond keeping notices that users of freqbrdf would inherit unawares. A
#   dependency under MPL-2.0 needs a decision of its own: an entry in WEAK_COPYLEFT_ACCEPTED
#   saying why.
FAMILIES = {
    "MIT": {
        "spdx": {"MIT", "MIT-0"},
        "classifiers": {"MIT License", "MIT No Attribution License (MIT-0)"},
        "names": {"MIT", "MIT License", "The MIT License", "The MIT License (MIT)"},
    },
    "BSD": {
        "spdx": {"BSD-2-Clause", "BSD-3-Clause", "0BSD"},
        "classifiers": {"BSD License"},
        "names": {"BSD", "BSD License", "BSD-2-Clause", "BSD-3-Clause", "BSD 2-Clause License",
                  "BSD 3-Clause License", "3-Clause BSD License", "New BSD License", "Modified BSD License"},
    },
    "Apache": {
        "spdx": {"Apache-2.0"},
        "classifiers": {"Apache Software License"},
        "names": {"Apache-2.0", "Apache 2.0", "Apache License 2.0", "Apache License, Version 2.0",
                  "Apache Software License"},
    },
    "PSF": {
        "spdx": {"PSF-2.0", "Python-2.0"},
        "classifiers": {"Python Software Foundation License"},
        "names": {"PSF", "PSF-2.0", "PSFL", "Python Software Foundation License"},
    },
    "ISC": {
        "spdx": {"ISC"},
        "classifiers": {"ISC License (ISCL)"},
        "names": {"ISC", "ISC License"},
    },
    "HPND": {  # Historical Permission Notice and Disclaimer, and the CMU licence (Pillow's), its variant
        "spdx": {"HPND", "MIT-CMU"},
        "classifiers": {"Historical Permission Notice and Disclaimer (HPND)"},
        "names": {"HPND"},
    },
    "zlib": {
        "spdx": {"Zlib"},
        "classifiers": {"zlib/libpng License"},
        "names": {"Zlib", "zlib"},
    },
    "public domain": {  # dedications, e.g. data files numpy ships under CC0-1.0
        "spdx": {"CC0-1.0", "Unlicense"},
        "classifiers": {"CC0 1.0 Universal (CC0 1.0) Public Domain Dedication", "The Unlicense (Unlicense)",
                        "Public Domain"},
        "names": {"Public Domain", "CC0-1.0", "Unlicense"},
    },
}
# SPDX exceptions that only add permissions to the licence they qualify (llvmlite's LLVM).
EXCEPTIONS = {"LLVM-exception"}

# Distributions whose metadata is missing or ambiguous, mapped by hand to an SPDX expression.
EXPLICIT = {
    # The OpenEXR wheel declares no licence (no License-Expression, License or classifier). The
    # OpenEXR project, and the LICENSE.md the wheel ships, are BSD-3-Clause:
    # https://github.com/AcademySoftwareFoundation/openexr/blob/main/LICENSE.md
    "openexr": "BSD-3-Clause",
    # xatlas (xatlas-python) has no classifier, and its License field is the whole licence text,
    # which is MIT (https://github.com/mworchel/xatlas-python/blob/main/LICENSE), as is the
    # xatlas library it wraps (https://github.com/jpcy/xatlas/blob/master/LICENSE).
    "xatlas": "MIT",
}

# Distributions under a weak-copyleft licence (MPL-2.0 only) accepted one by one, each with the
# reason.
WEAK_COPYLEFT = {"MPL-2.0", "Mozilla Public License 2.0 (MPL 2.0)"}
WEAK_COPYLEFT_ACCEPTED: dict[str, str] = {
    # Ray (the batch runner's engine) needs requests, which needs certifi. certifi is Mozilla's CA
    # bundle as data, used unmodified; MPL-2.0's source obligation binds only changes to its files,
    # and its source is the published distribution itself.
    "certifi": "Mozilla's CA certificates, unmodified data, pulled in by Ray through requests",
}

SPDX_IDS = {spdx: family for family, forms in FAMILIES.items() for spdx in forms["spdx"]}
CLASSIFIER_FAMILIES = {c: family for family, forms in FAMILIES.items() for c in forms["classifiers"]}
NAME_FAMILIES = {name.lower(): family for family, forms in FAMILIES.items() for name in forms["names"]}
# Classifiers that say nothing about which licence it is
UNINFORMATIVE_CLASSIFIERS = {"License :: OSI Approved"}


@dataclass
class Verdict:
    permissive: bool
    licences: str  # what was read, for the messages
    reason: str = ""


def spdx_permissive(expression: str) -> bool:
    """Whether an SPDX licence expression allows use under permissive terms only: OR needs one
    permissive choice, AND needs all, WITH needs a permissive licence and a permission-only
    exception. Unknown identifiers (LicenseRef-..., anything not in FAMILIES) are not permissive."""
    tokens = re.findall(r"\(|\)|[A-Za-z0-9.+:-]+", expression)
    position = 0

    def peek():
        return tokens[position] if position < len(tokens) else None

    def take():
        nonlocal position
        position += 1
        return tokens[position - 1]

    def primary() -> bool:
        token = take()
        if token == "(":
            value = disjunction()
            if take() != ")":
                raise ValueError(f"unbalanced parentheses in {expression!r}")
            return value
        if token.upper() in {"AND", "OR", "WITH", ")"}:
            raise ValueError(f"malformed SPDX expression {expression!r}")
        allowed = token.removesuffix("+") in SPDX_IDS  # "or later" of a permissive licence
        if peek() is not None and peek().upper() == "WITH":
            take()
            allowed = allowed and take() in EXCEPTIONS
        return allowed

    def conjunction() -> bool:
        value = primary()
        while peek() is not None and peek().upper() == "AND":
            take()
            value = primary() and value
        return value

    def disjunction() -> bool:
        value = conjunction()
        while peek() is not None and peek().upper() == "OR":
            take()
            value = conjunction() or value
        return value

    if not tokens:
        raise ValueError("empty SPDX expression")
    value = disjunction()
    if position != len(tokens):
        raise ValueError(f"malformed SPDX expression {expression!r}")
    return value


def looks_like_spdx(text: str) -> bool:
    """Whether a one-line License field reads as an SPDX expression ("BSD-3-Clause",
    "MIT OR Apache-2.0", "GPL-3.0-or-later"): operators, parentheses and identifiers only."""
    tokens = re.findall(r"[^\s()]+", text)
    return bool(tokens) and all(
        token.upper() in {"AND", "OR", "WITH"} or token in SPDX_IDS
        or re.fullmatch(r"[A-Za-z][A-Za-z0-9.+-]*[0-9-][A-Za-z0-9.+-]*", token) is not None
        for token in tokens)


def permissive_or_malformed(expression: str) -> tuple[bool, str]:
    try:
        return spdx_permissive(expression), ""
    except ValueError as error:
        return False, str(error)


def classify(name: str, expression: str | None, license_field: str | None, classifiers: list[str]) -> Verdict:
    """The licence verdict of one distribution from its metadata fields: an EXPLICIT mapping,
    else its License-Expression, else its "License ::" classifiers and License field together
    (each must name an allowed family, and at least one must name one)."""
    key = canonicalize_name(name)
    if key in EXPLICIT:
        return Verdict(spdx_permissive(EXPLICIT[key]), f"{EXPLICIT[key]} (mapped by hand)")
    if expression:
        permissive, problem = permissive_or_malformed(expression)
        return Verdict(permissive, expression, problem or ("" if permissive else
                                                            "its License-Expression is not permissive only"))
    found, refused = [], []
    for classifier in classifiers:
        if not classifier.startswith("License ::") or classifier in UNINFORMATIVE_CLASSIFIERS:
            continue
        short = classifier.removeprefix("License :: OSI Approved :: ").removeprefix("License :: ")
        (found if short in CLASSIFIER_FAMILIES else refused).append(short)
    text = (license_field or "").strip()
    if text and "\n" not in text and len(text) <= 80:  # a name or an expression, not a licence text
        if text.lower() in NAME_FAMILIES:
            found.append(text)
        elif looks_like_spdx(text) and permissive_or_malformed(text)[0]:
            found.append(text)
        else:
            refused.append(f"License {text!r}")
    described = "; ".join(found + refused)
    if refused:
        return Verdict(False, described, f"not (known as) a permissive licence: {'; '.join(refused)}")
    if not found:
        return Verdict(False, described or "nothing",
                       "no licence in its metadata that this test can read: map it in EXPLICIT, citing its licence")
    return Verdict(True, described)


def weak_copyleft_only(fields: tuple[str | None, str | None, list[str]]) -> bool:
    """Whether every licence the metadata names is MPL-2.0 (as expression, License or classifier)."""
    expression, license_field, classifiers = fields
    named = [expression] if expression else [
        *(c.removeprefix("License :: OSI Approved :: ") for c in classifiers if c.startswith("License ::")),
        *([license_field.strip()] if license_field and "\n" not in license_field.strip() else [])]
    return bool(named) and all(name in WEAK_COPYLEFT for name in named)


def accepted_verdict(name: str, expression: str | None, license_field: str | None,
                     classifiers: list[str], accepted: dict[str, str]) -> Verdict:
    """`classify`, but a distribution under MPL-2.0 only that ``accepted`` names passes, with its reason."""
    verdict = classify(name, expression, license_field, classifiers)
    key = canonicalize_name(name)
    if not verdict.permissive and key in accepted and weak_copyleft_only((expression, license_field, classifiers)):
        return Verdict(True, f"{verdict.licences} (weak copyleft, accepted: {accepted[key]})")
    return verdict


def distribution_verdict(distribution: metadata.Distribution) -> Verdict:
    fields = distribution.metadata
    return accepted_verdict(fields["Name"], fields.get("License-Expression"), fields.get("License"),
                            fields.get_all("Classifier") or [], WEAK_COPYLEFT_ACCEPTED)


def root_requirements() -> list[str]:
    """freqbrdf's runtime requirements: the checkout's pyproject.toml if the tests run from one,
    else the installed distribution's (without extras)."""
    for folder in Path(__file__).resolve().parents:
        pyproject = folder / "pyproject.toml"
        if pyproject.is_file():
            try:
                import tomllib
            except ModuleNotFoundError:  # Python 3.10
                break
            project = tomllib.loads(pyproject.read_text()).get("project", {})
            if project.get("name") == "freqbrdf":
                return list(project.get("dependencies", []))
    return [requirement for requirement in metadata.requires("freqbrdf") or []
            if not Requirement(requirement).marker or Requirement(requirement).marker.evaluate({"extra": ""})]


def runtime_closure() -> tuple[dict[str, metadata.Distribution], list[str]]:
    """Every distribution freqbrdf needs at run time, by canonical name, and the requirements that
    are not installed."""
    found: dict[str, metadata.Distribution] = {}
    missing: list[str] = []
    pending = [Requirement(text) for text in root_requirements()]
    while pending:
        requirement = pending.pop()
        if requirement.marker is not None and not requirement.marker.evaluate({"extra": ""}):
            continue  # another platform's, or an extra's
        key = canonicalize_name(requirement.name)
        if key in found:
            continue
        try:
            distribution = metadata.distribution(requirement.name)
        except metadata.PackageNotFoundError:
            missing.append(str(requirement))
            continue
        found[key] = distribution
        pending.extend(Requirement(text) for text in distribution.requires or [])
    return dict(sorted(found.items())), missing


def licence_table() -> str:
    """One line per runtime dependency: name, version, licence read, verdict."""
    closure, _ = runtime_closure()
    lines = []
    for key, distribution in closure.items():
        verdict = distribution_verdict(distribution)
        lines.append(f"{key} {distribution.version}: {verdict.licences}"
                     f"{'' if verdict.permissive else '  <- ' + verdict.reason}")
    return "\n".join(lines)


def test_every_runtime_dependency_has_a_permissive_licence():
    closure, missing = runtime_closure()
    assert not missing, f"runtime requirements not installed, their licences unread: {missing}"
    assert {"numpy", "scipy", "numba", "mitsuba", "openexr", "typer"} <= closure.keys()
    refused = {key: distribution_verdict(distribution) for key, distribution in closure.items()}
    refused = {key: verdict for key, verdict in refused.items() if not verdict.permissive}
    assert not refused, "\n".join(f"{key}: {verdict.licences} ({verdict.reason})" for key, verdict in refused.items())


def test_the_spherical_harmonic_transforms_are_not_ducc0s():
    closure, _ = runtime_closure()
    assert "ducc0" not in closure  # GPL-2.0-or-later


@pytest.mark.parametrize("expression, permissive", [
    ("MIT", True),
    ("BSD-2-Clause AND Apache-2.0 WITH LLVM-exception", True),
    ("Apache-2.0 OR BSD-2-Clause", True),
    ("(MIT OR GPL-3.0-only) AND BSD-3-Clause", True),  # may be used under MIT
    ("MIT AND GPL-3.0-or-later", False),
    ("GPL-2.0-or-later", False),
    ("LGPL-3.0-only", False),
    ("MPL-2.0", False),
    ("MPL-2.0 AND MIT", False),
    ("Apache-2.0 WITH Classpath-exception-2.0", False),  # an exception this test does not know
    ("LicenseRef-Proprietary", False),
    ("CC-BY-NC-4.0", False),
])
def test_spdx_expressions_are_read_with_their_operators(expression, permissive):
    assert spdx_permissive(expression) is permissive
    assert classify("example", expression, None, []).permissive is permissive


@pytest.mark.parametrize("license_field, classifiers, permissive", [
    (None, ["License :: OSI Approved :: MIT License"], True),
    ("BSD", ["License :: OSI Approved :: BSD License"], True),
    ("Apache-2.0", [], True),
    ("The MIT License (MIT)\n\nCopyright (c) ...", ["License :: OSI Approved :: MIT License"], True),
    (None, ["License :: OSI Approved :: GNU General Public License v2 or later (GPLv2+)"], False),
    (None, ["License :: OSI Approved :: MIT License",
            "License :: OSI Approved :: GNU Lesser General Public License v3 (LGPLv3)"], False),
    (None, ["License :: Other/Proprietary License"], False),
    (None, ["License :: OSI Approved :: Mozilla Public License 2.0 (MPL 2.0)"], False),
    ("GPL-3.0-or-later", ["License :: OSI Approved :: MIT License"], False),
    ("Free for non-commercial use", [], False),
    ("MIT License\n\nPermission is hereby granted ...", [], False),  # a text: ambiguous
    (None, ["License :: OSI Approved"], False),  # says nothing
    (None, [], False),
])
def test_classifiers_and_license_fields_are_read_strictly(license_field, classifiers, permissive):
    assert classify("example", None, license_field, classifiers).permissive is permissive


def test_a_weak_copyleft_dependency_passes_only_once_accepted_by_name():
    mpl = ("MPL-2.0", None, [])
    assert not accepted_verdict("certifi", *mpl, {}).permissive
    assert accepted_verdict("certifi", *mpl, {"certifi": "a reason"}).permissive
    assert accepted_verdict("certifi", None, "MPL-2.0", ["License :: OSI Approved :: Mozilla Public License 2.0 (MPL 2.0)"],
                            {"certifi": "a reason"}).permissive
    assert not accepted_verdict("other", *mpl, {"certifi": "a reason"}).permissive
    assert not accepted_verdict("certifi", "MPL-2.0 AND GPL-3.0-only", None, [], {"certifi": "a reason"}).permissive
    assert not accepted_verdict("certifi", "GPL-3.0-only", None, [], {"certifi": "a reason"}).permissive


def test_explicit_mappings_are_for_metadata_that_cannot_be_read():
    # Drop an entry once its distribution's metadata says what its licence is.
    for key in EXPLICIT:
        try:
            distribution = metadata.distribution(key)
        except metadata.PackageNotFoundError:
            continue
        fields = distribution.metadata
        verdict = classify("not-mapped", fields.get("License-Expression"), fields.get("License"),
                           fields.get_all("Classifier") or [])
        assert not verdict.permissive, f"{key}'s metadata now reads {verdict.licences}: remove it from EXPLICIT"


def test_ducc0_would_be_refused():
    try:
        distribution = metadata.distribution("ducc0")
    except metadata.PackageNotFoundError:
        pytest.skip("ducc0 is not installed")
    assert not distribution_verdict(distribution).permissive


# --------------------------------------------------------------------------------------------
# What freqbrdf itself ships


REPOSITORY = next((folder for folder in Path(__file__).resolve().parents if (folder / "pyproject.toml").is_file()), None)


@pytest.mark.skipif(REPOSITORY is None or not (REPOSITORY / "LICENSE").is_file(), reason="not run from a checkout")
def test_license_is_mit_as_pyproject_declares_and_notice_lists_the_bundled_files():
    tomllib = pytest.importorskip("tomllib", reason="tomllib is Python 3.11's")
    from freqbrdf import assets

    assert tomllib.loads((REPOSITORY / "pyproject.toml").read_text())["project"]["license"] == "MIT"
    licence = (REPOSITORY / "LICENSE").read_text()
    assert licence.startswith("MIT License") and "freqbrdf authors" in licence
    notice = (REPOSITORY / "NOTICE").read_text()
    for name in ["model-viewer-umd.min.js", "LICENSE.model-viewer", "Apache License, Version 2.0",
                 *assets.list_envmaps(), *assets.list_meshes(), *assets.list_materials()]:
        assert name in notice, name
