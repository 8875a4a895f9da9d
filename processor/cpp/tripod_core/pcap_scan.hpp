// SPDX-License-Identifier: BSD-3-Clause
// One pass over a buffer of classic-pcap records: the UDP payloads of plain Ethernet/IPv4/UDP
// frames found in place, data packets copied out back to back.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

namespace tripod {

/// Layout of the capture (from its global header).
struct PcapLayout {
    bool big_endian = false;  ///< record headers in big-endian byte order
    bool nanosecond = false;  ///< magic a1b23c4d: the fraction is ns, else us
    std::uint32_t linktype = 1;
};

/// What scan_pcap_records found. Records are classified on the "plain" path (Ethernet,
/// IPv4 without fragmentation, UDP: every Velodyne capture), exactly as tripod's Python
/// reader does; any other record is left to the caller ("slow"), with its place.
struct PcapScan {
    std::size_t consumed = 0;  ///< bytes of the whole records scanned (the rest is incomplete)
    std::size_t records = 0;   ///< whole records scanned
    bool oversize = false;     ///< stopped at a record claiming more than max_record_bytes
    std::uint32_t oversize_bytes = 0;

    /// plain records whose UDP payload has data_size bytes: payloads back to back
    std::vector<std::uint8_t> data;
    std::vector<std::int64_t> data_t_ns;  ///< capture time [ns] (host_realtime of the capturer)
    std::vector<std::uint16_t> data_port; ///< UDP destination port
    std::vector<std::int64_t> data_record; ///< index of the record in this scan

    /// plain records with another payload size (position packets, ...): where the payload is
    std::vector<std::int64_t> other_t_ns, other_offset;
    std::vector<std::int32_t> other_length;
    std::vector<std::uint16_t> other_port;

    /// records off the plain path: where the captured frame is, and the record's index
    std::vector<std::int64_t> slow_t_ns, slow_offset, slow_record;
    std::vector<std::int32_t> slow_length;
};

/// Scan the whole pcap records at the start of `buf` (record header + frame each).
///
/// @param buf, len          record bytes, starting at a record header
/// @param layout            the capture's byte order, time resolution and link type
/// @param data_size         payload size of a data packet [bytes] (1206 for Velodyne)
/// @param max_record_bytes  a record claiming more stops the scan (corrupt file)
PcapScan scan_pcap_records(const std::uint8_t* buf, std::size_t len, const PcapLayout& layout,
                           std::size_t data_size, std::uint32_t max_record_bytes);

}  // namespace tripod
