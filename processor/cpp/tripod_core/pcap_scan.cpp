// SPDX-License-Identifier: BSD-3-Clause
#include "tripod_core/pcap_scan.hpp"

#include <cstring>

namespace tripod {
namespace {

inline std::uint32_t rd32(const std::uint8_t* p, bool big_endian) {
    if (big_endian)
        return (std::uint32_t(p[0]) << 24) | (std::uint32_t(p[1]) << 16) |
               (std::uint32_t(p[2]) << 8) | std::uint32_t(p[3]);
    return std::uint32_t(p[0]) | (std::uint32_t(p[1]) << 8) | (std::uint32_t(p[2]) << 16) |
           (std::uint32_t(p[3]) << 24);
}
inline std::uint16_t be16(const std::uint8_t* p) {
    return static_cast<std::uint16_t>((p[0] << 8) | p[1]);
}

constexpr std::uint32_t kLinktypeEthernet = 1;

}  // namespace

PcapScan scan_pcap_records(const std::uint8_t* buf, std::size_t len, const PcapLayout& layout,
                           std::size_t data_size, std::uint32_t max_record_bytes) {
    PcapScan out;
    out.data.reserve(len);  // an upper bound: the payloads are a part of the records
    const std::int64_t scale = layout.nanosecond ? 1 : 1000;
    std::size_t pos = 0;
    while (len - pos >= 16) {
        const std::uint8_t* h = buf + pos;
        const std::uint32_t sec = rd32(h, layout.big_endian);
        const std::uint32_t frac = rd32(h + 4, layout.big_endian);
        const std::uint32_t incl = rd32(h + 8, layout.big_endian);
        if (incl > max_record_bytes) {
            out.oversize = true;
            out.oversize_bytes = incl;
            break;
        }
        if (len - pos - 16 < incl) break;  // the record continues past the buffer
        const std::size_t start = pos + 16;
        const std::size_t end_rec = start + incl;
        const std::int64_t t_ns = std::int64_t(sec) * 1000000000 + std::int64_t(frac) * scale;
        const std::uint8_t* f = buf + start;
        bool plain = false;
        // Ethernet + IPv4 without options, not fragmented, + UDP (tripod.pcap's inline path)
        if (layout.linktype == kLinktypeEthernet && incl >= 42 && f[12] == 8 && f[13] == 0 &&
            f[14] == 0x45 && f[23] == 17 && !(be16(f + 20) & 0x3FFF)) {
            const std::uint16_t ulen = be16(f + 38);
            const std::size_t end = ulen >= 8 ? start + 34 + ulen : start + 14 + be16(f + 16);
            if (end <= end_rec) {
                plain = true;
                const std::size_t p0 = start + 42;
                const std::size_t plen = end > p0 ? end - p0 : 0;
                const std::uint16_t port = be16(f + 36);
                if (plen == data_size) {
                    out.data.insert(out.data.end(), buf + p0, buf + p0 + plen);
                    out.data_t_ns.push_back(t_ns);
                    out.data_port.push_back(port);
                    out.data_record.push_back(static_cast<std::int64_t>(out.records));
                } else {
                    out.other_t_ns.push_back(t_ns);
                    out.other_offset.push_back(static_cast<std::int64_t>(p0));
                    out.other_length.push_back(static_cast<std::int32_t>(plen));
                    out.other_port.push_back(port);
                }
            }
        }
        if (!plain) {
            out.slow_t_ns.push_back(t_ns);
            out.slow_offset.push_back(static_cast<std::int64_t>(start));
            out.slow_length.push_back(static_cast<std::int32_t>(incl));
            out.slow_record.push_back(static_cast<std::int64_t>(out.records));
        }
        ++out.records;
        pos = end_rec;
    }
    out.consumed = pos;
    return out;
}

}  // namespace tripod
