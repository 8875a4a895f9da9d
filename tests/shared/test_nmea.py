# SPDX-License-Identifier: BSD-3-Clause
"""tripod_shared.nmea: checksums, GPRMC time, and the writer/parser round trip."""

import datetime as dt

from tripod_shared import nmea



def test_checksum_of_known_sentence():
    body = "GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,"
    assert nmea.checksum(body) == "47"  # the textbook example sentence ends in *47
    assert nmea.checksum_ok(f"${body}*47")
    assert not nmea.checksum_ok(f"${body}*48")
    assert not nmea.checksum_ok(body)
    assert not nmea.checksum_ok(f"${body}*zz")


def test_rmc_time_whole_seconds():
    t = nmea.rmc_unix_ns("$GPRMC,101530.75,A,4807.038,N,01131.000,E,0.0,0.0,260326,,,A*00")
    assert t == int(dt.datetime(2026, 3, 26, 10, 15, 30, tzinfo=dt.timezone.utc).timestamp()) * 10**9


def test_rmc_rejects_other_and_broken_sentences():
    assert nmea.rmc_unix_ns("$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47") is None
    assert nmea.rmc_unix_ns("$GPRMC,1015,A") is None            # too few fields
    assert nmea.rmc_unix_ns("$GPRMC,xx1530,A,,,,,,,260326,,") is None  # time does not parse
    assert nmea.rmc_unix_ns("$GPRMC,101530,A,,,,,,,329926,,") is None  # no such date
    assert nmea.rmc_unix_ns("") is None


def test_format_then_parse_round_trip():
    t_ns = int(dt.datetime(2026, 11, 26, 5, 59, 59, tzinfo=dt.timezone.utc).timestamp()) * 10**9
    s = nmea.format_rmc(t_ns + 420_000_000, 48.1173, -11.5167)
    assert nmea.checksum_ok(s)
    assert nmea.sentence_type(s) == "GPRMC"
    assert nmea.rmc_unix_ns(s) == t_ns
    f = s.split(",")
    assert f[2] == "A" and f[4] == "N" and f[6] == "W"
