"""The README stays a short page for an owner and a newcomer, and the docs' links resolve."""
import os
import pathlib
import re
import subprocess

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
PAGES = [ROOT / 'README.md'] + sorted((ROOT / 'docs').glob('*.md'))
# [text](target) and ![alt](target), the target up to a space (a title) or the closing parenthesis
LINK = re.compile(r'!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+"[^"]*")?\s*\)')
FENCE = re.compile(r'^```.*?^```', re.M | re.S)
CODE = re.compile(r'`[^`\n]*`')


def relative_links(page):
    text = CODE.sub('', FENCE.sub('', page.read_text(encoding='utf-8')))
    for target in LINK.findall(text):
        if re.match(r'^[a-zA-Z][a-zA-Z0-9+.-]*:', target) or target.startswith('#'):
            continue  # http:, https:, mailto: ... and links within the page
        yield target


def test_readme_is_at_most_300_lines():
    lines = (ROOT / 'README.md').read_text(encoding='utf-8').splitlines()
    assert len(lines) <= 300, 'README.md has {} lines: move details to a page under docs/'.format(len(lines))


def test_the_pages_exist():
    names = {p.name for p in PAGES}
    for name in ('results.md', 'realistic-brick.md', 'safety.md', 'benchmarks.md'):
        assert name in names


@pytest.mark.parametrize('page', PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_point_to_existing_files(page):
    missing = []
    for target in relative_links(page):
        path = target.split('#', 1)[0]
        if path and not (page.parent / path).exists():
            missing.append(target)
    assert not missing, '{}: links to missing files: {}'.format(page.relative_to(ROOT), missing)


def test_the_readme_points_to_every_page():
    linked = {pathlib.PurePosixPath(t.split('#', 1)[0]).name for t in relative_links(ROOT / 'README.md')}
    for page in PAGES[1:]:
        assert page.name in linked, 'README.md does not point to docs/{}'.format(page.name)


def test_the_link_pattern_finds_links():
    assert list(relative_links_of('see [a](docs/a.md) and ![p](x.png "t") and [w](https://e.org)')) == \
        ['docs/a.md', 'x.png']


def relative_links_of(text, tmp=None):
    import tempfile
    with tempfile.TemporaryDirectory() as d:
        p = pathlib.Path(d) / 'p.md'
        p.write_text(text, encoding='utf-8')
        return list(relative_links(p))


@pytest.mark.parametrize("target, usage", [("replay", "usage: make replay LOG="), ("watch", "usage: make watch HOST=")])
def test_a_target_missing_its_argument_says_so_before_building_the_venv(tmp_path, target, usage):
    """make replay without LOG, make watch without HOST: the usage line at once, not after the
    40 s of a venv build (VENV points where there is none)."""
    venv = tmp_path / "no-venv"
    env = dict(os.environ)
    for name in ("LOG", "HOST"):
        env.pop(name, None)
    p = subprocess.run(["make", "-s", target, "VENV=%s" % venv], cwd=str(ROOT), env=env, stdout=subprocess.PIPE,
                       stderr=subprocess.PIPE, universal_newlines=True, timeout=60)
    assert p.returncode == 2 and usage in p.stderr, p.stderr
    assert not venv.exists()


def test_the_safety_page_shows_the_exit_codes_table():
    from tipbot_fw.guard.exit_codes import markdown_table
    assert markdown_table() + "\n" in (ROOT / "docs" / "safety.md").read_text(encoding="utf-8")
