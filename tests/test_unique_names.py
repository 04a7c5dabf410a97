"""Test modules are collected by their file name (pytest's default import mode puts each test folder on
sys.path): two with one name in different folders stop the whole run at collection."""

from collections import Counter
from pathlib import Path


def test_every_test_module_has_its_own_name():
    names = Counter(p.name for p in Path(__file__).parent.rglob("test_*.py"))
    assert [n for n, count in names.items() if count > 1] == []
