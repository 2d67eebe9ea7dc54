"""Where recorded trajectories come from: data files that installed packages ship, read into one table of reports.

Nothing is copied into the repository: each :class:`Source` names a package and a file inside it, found at run
time with :func:`importlib.util.find_spec` (which locates a package without importing it, so a data package's
own heavy imports never run) and read by the source's reader into :class:`Reports`: per report the target's id,
the time (s, UTC epoch), latitude and longitude (degrees), height (m), the reported speed (m/s, NaN where the
data has none) and whether the target said it was at anchor, moored or on the ground; per target a label (vessel
name or call sign) for the viewer.

The sources (``zentrack[real]`` installs their packages):

- ``ais-nyharbor``: AIS reports of New York Harbor, 2020-06-30 00:00-01:00 UTC (295 vessels), from
  ``tracktable-data`` (BSD-3-Clause; the AIS data are the US Coast Guard's, published by MarineCadastre.gov);
- ``adsb-paris``: OpenSky ADS-B states of aircraft around Paris, 2021-10-07 (213 aircraft, three hours),
  ``quickstart.json.gz`` of ``traffic`` (MIT; OpenSky Network data, free for research and non-commercial use,
  to be cited as Schäfer et al., *Bringing up OpenSky*, IPSN 2014).
"""
from __future__ import annotations

import csv
import gzip
import importlib.util
import json
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

Array = np.ndarray

KNOT = 1852.0 / 3600.0  #: m/s
FOOT = 0.3048  #: m
#: AIS navigational status codes of a vessel that is not under way: 1 at anchor, 5 moored, 6 aground
AIS_STILL = (1.0, 5.0, 6.0)
#: the extra that installs every source's package
EXTRA = "zentrack[real]"


class RecordingUnavailable(ValueError):
    """A source's package is not installed, or its file is missing or unreadable (one line naming it)."""


@dataclass(frozen=True)
class Reports:
    """Position reports of many targets, one row each (not sorted): ``ids`` ``(R,)`` str, ``t`` (s, UTC epoch),
    ``lat``/``lon`` (deg), ``height`` (m), ``speed`` (m/s, NaN: not reported), ``still`` (the target reported
    itself at anchor, moored or on the ground); ``labels`` maps an id to its name or call sign."""

    ids: Array
    t: Array
    lat: Array
    lon: Array
    height: Array
    speed: Array
    still: Array
    labels: dict[str, str]

    def __len__(self) -> int:
        return int(self.t.size)


@dataclass(frozen=True)
class Source:
    """A recording: the package that ships it, the file inside the package, what kind of targets it holds and
    the function that reads the file."""

    name: str
    package: str
    pip_name: str
    path: str
    targets: str  #: "vessels" or "aircraft"
    reader: Callable[[Path], Reports]
    terms: str

    def locate(self) -> Path:
        """The data file inside the installed package; :class:`RecordingUnavailable` (one line) if absent."""
        spec = importlib.util.find_spec(self.package)
        if spec is None or not spec.submodule_search_locations:
            raise RecordingUnavailable(f"{self.name}: its data package {self.pip_name!r} is not installed "
                                       f"(pip install '{EXTRA}')")
        path = Path(next(iter(spec.submodule_search_locations))) / self.path
        if not path.is_file():
            raise RecordingUnavailable(f"{self.name}: {self.pip_name!r} is installed but has no {self.path} "
                                       f"(reinstall it: pip install --force-reinstall '{EXTRA}')")
        return path

    def read(self) -> Reports:
        path = self.locate()
        try:
            return self.reader(path)
        except (OSError, ValueError, KeyError, TypeError, EOFError) as exc:
            raise RecordingUnavailable(f"{self.name}: cannot read {path.name}: {exc}") from None


def _float(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        return float("nan")


def _epoch(text: str) -> float:
    return datetime.fromisoformat(text).replace(tzinfo=UTC).timestamp()


def read_ais_csv(path: Path) -> Reports:
    """MarineCadastre AIS CSV (``BaseDateTime, LON, LAT, MMSI, SOG, COG, ..., VesselName, ..., CallSign, ...,
    Status``): the MMSI is the id, the vessel name (else the call sign, else the MMSI) the label, height 0."""
    ids, t, lat, lon, speed, still = [], [], [], [], [], []
    labels: dict[str, str] = {}
    with open(path, newline="", encoding="utf-8") as fh:
        for row in csv.DictReader(fh):
            mmsi = row["MMSI"].strip()
            ids.append(mmsi)
            t.append(_epoch(row["BaseDateTime"]))
            lat.append(_float(row["LAT"]))
            lon.append(_float(row["LON"]))
            speed.append(_float(row["SOG"]) * KNOT)
            still.append(_float(row.get("Status", "")) in AIS_STILL)
            if mmsi not in labels:
                labels[mmsi] = (row.get("VesselName") or row.get("CallSign") or mmsi).strip() or mmsi
    n = len(ids)
    return Reports(np.array(ids, dtype=str), np.array(t), np.array(lat), np.array(lon), np.zeros(n),
                   np.array(speed), np.array(still, dtype=bool), labels)


def read_adsb_json(path: Path) -> Reports:
    """OpenSky state vectors as ``traffic`` ships them (a gzipped JSON list of ``{timestamp (ms), icao24,
    callsign, latitude, longitude, altitude (ft), groundspeed (kn), onground, ...}``): the ICAO 24-bit address is
    the id, the call sign the label, the barometric altitude the height."""
    with gzip.open(path, "rt", encoding="utf-8") as fh:
        states = json.load(fh)
    if not isinstance(states, list):
        raise ValueError("expected a list of state vectors")
    n = len(states)
    ids = np.empty(n, dtype=object)
    t, lat, lon, height, speed = (np.full(n, np.nan) for _ in range(5))
    still = np.zeros(n, dtype=bool)
    labels: dict[str, str] = {}
    for i, s in enumerate(states):
        icao = str(s["icao24"])
        ids[i] = icao
        t[i] = float(s["timestamp"]) / 1000.0
        for arr, key in ((lat, "latitude"), (lon, "longitude"), (height, "altitude"), (speed, "groundspeed")):
            value = s.get(key)
            arr[i] = float(value) if value is not None else np.nan
        still[i] = bool(s.get("onground", False))
        if s.get("callsign") and icao not in labels:
            labels[icao] = str(s["callsign"]).strip()
    return Reports(ids.astype(str), t, lat, lon, height * FOOT, speed * KNOT, still, labels)


SOURCES: dict[str, Source] = {s.name: s for s in (
    Source("ais-nyharbor", "tracktable_data", "tracktable-data",
           "python_example_data/NYHarbor_2020_06_30_first_hour.csv", "vessels", read_ais_csv,
           "AIS data of the US Coast Guard (MarineCadastre.gov, public domain), shipped by tracktable-data "
           "(BSD-3-Clause)"),
    Source("adsb-paris", "traffic", "traffic", "data/samples/collections/quickstart.json.gz", "aircraft",
           read_adsb_json,
           "OpenSky Network data (free for research and non-commercial use; cite Schäfer et al., IPSN 2014), "
           "shipped by traffic (MIT)"),
)}


def source(name: str) -> Source:
    """The source called ``name``; ValueError listing the known ones."""
    try:
        return SOURCES[name]
    except KeyError:
        raise ValueError(f"unknown recording source {name!r}; known: {', '.join(SOURCES)}") from None
