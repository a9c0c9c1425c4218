"""The README's Python example runs as written."""

import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def test_readme_python_examples_run():
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)
    assert blocks, "the README has a Python example"
    for code in blocks:
        exec(compile(code, str(README), "exec"), {"__name__": "readme"})


def test_readme_machine_figures_match_the_description():
    """The derived figures the README quotes are the machine's (docs checked against code)."""
    from models import build_reference_machine
    from scenarios.closed_loop_scenarios import threshold

    text = README.read_text()
    m = build_reference_machine()
    static = m.total_mass * m.gravity / 4
    assert f"# {m.total_mass / 1000:.1f} t" in text
    assert f"static wheel load ({static / 1000:.1f} kN)" in text
    assert f"threshold {threshold() / 1000:.2f} kN = 10 % of the static wheel load" in text


def test_reference_machine_docstring_mass_is_the_description_s():
    import models.reference_machine as rm

    m = rm.build_reference_machine()
    assert f"({m.total_mass / 1000:.1f} t)" in rm.__doc__.splitlines()[0]
