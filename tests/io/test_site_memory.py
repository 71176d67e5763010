"""The TUI's last site answer: kept, read back, and an unusable file offers nothing."""

from __future__ import annotations

from pathlib import Path

from canimucal.io.site_memory import LastSite, read_last_site, save_last_site


def test_the_last_answer_is_read_back(tmp_path: Path) -> None:
    path = tmp_path / "state" / "last-site.json"
    last = LastSite("Ann", "Bay 3", -33.9, 12.0, 9.7963)
    save_last_site(path, last)
    assert read_last_site(path) == last
    assert read_last_site(None) == LastSite() and read_last_site(tmp_path / "no.json") == LastSite()


def test_a_bad_file_offers_nothing_wrong(tmp_path: Path) -> None:
    path = tmp_path / "last-site.json"
    path.write_text("{not json")
    assert read_last_site(path) == LastSite()
    path.write_text('{"operator": 7, "site_name": "Bay", "latitude_deg": NaN, "g": true}')
    assert read_last_site(path) == LastSite(site_name="Bay")
