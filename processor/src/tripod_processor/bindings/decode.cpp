// SPDX-License-Identifier: BSD-3-Clause
// Bindings: the classic-pcap record scan (tripod_core/pcap_scan.hpp) and the batch VLP-16
// decoder (tripod_core/vlp16_decoder.hpp). Conversions and docstrings only; one call per buffer
// of records or chunk of packets, the GIL released while C++ works. Python owners:
// tripod_processor.io.pcap (the scan) and tripod_processor.decode.native (the decoder).
#include <nanobind/stl/optional.h>

#include <optional>

#include "common.hpp"
#include "tripod_core/pcap_scan.hpp"
#include "tripod_core/vlp16_decoder.hpp"

namespace nb = nanobind;
using namespace tripod_bind;

namespace {

using BytesIn = nb::ndarray<const std::uint8_t, nb::ndim<1>, nb::c_contig, nb::device::cpu>;
using PacketsIn =
    nb::ndarray<const std::uint8_t, nb::shape<-1, 1206>, nb::c_contig, nb::device::cpu>;
using I64In = nb::ndarray<const std::int64_t, nb::shape<-1>, nb::c_contig, nb::device::cpu>;
using F64Table = nb::ndarray<const double, nb::shape<16, 12>, nb::c_contig, nb::device::cpu>;
using RingsIn = nb::ndarray<const std::uint8_t, nb::shape<16>, nb::c_contig, nb::device::cpu>;

template <typename T, int D>
using Out = nb::ndarray<nb::numpy, T, nb::ndim<D>>;

/// What one scan of pcap records found, as numpy arrays (the result class of the scan).
struct PcapScanArrays {
    std::size_t consumed = 0, records = 0;
    std::uint32_t oversize_bytes = 0;  // 0: no oversize record
    Out<std::uint8_t, 2> data;         // (n, data_size) payloads of plain UDP records
    Out<std::int64_t, 1> data_t_ns, data_record;
    Out<std::uint16_t, 1> data_port;
    Out<std::int64_t, 2> other;  // (k, 4) [t_ns, payload offset, length, port]
    Out<std::int64_t, 2> slow;   // (m, 4) [t_ns, frame offset, length, record index]
};

/// What one decoder call gave, as numpy arrays (the result class of Vlp16Decoder.decode).
struct DecodedChunk {
    Out<std::uint8_t, 2> points;  // (M, 20) Vlp16Point records
    Out<float, 1> time_s;         // (M,) or empty
    Out<std::int64_t, 1> block_first_point;
    Out<std::uint8_t, 1> status;
    bool time_offset_clipped = false;
    std::uint8_t return_type_after = tripod::kReturnTypeUnknown;
};

/// The decoder's points seen as bytes (numpy gets (M, 20) uint8 and views it as POINT_DTYPE).
struct PointBytes {
    std::unique_ptr<tripod::Vlp16Point[]> points;
    std::uint8_t* data() { return reinterpret_cast<std::uint8_t*>(points.get()); }
};

/// Columns of the (16, 12) calibration table, in this order (velodyne-decoder's LaserCorrection).
tripod::Vlp16Calibration calibration_from(const F64Table& t, double distance_resolution_m,
                                          const RingsIn& rings) {
    tripod::Vlp16Calibration c;
    c.distance_resolution_m = static_cast<float>(distance_resolution_m);
    for (int l = 0; l < 16; ++l) {
        auto& k = c.lasers[l];
        auto v = [&](int col) { return t(l, col); };
        k.rot_correction = static_cast<float>(v(0));
        k.vert_correction = static_cast<float>(v(1));
        k.dist_correction = static_cast<float>(v(2));
        k.two_pt_correction_available = v(3) != 0;
        k.dist_correction_x = static_cast<float>(v(4));
        k.dist_correction_y = static_cast<float>(v(5));
        k.vert_offset_correction = static_cast<float>(v(6));
        k.horiz_offset_correction = static_cast<float>(v(7));
        k.max_intensity = static_cast<int>(v(8));
        k.min_intensity = static_cast<int>(v(9));
        k.focal_distance = static_cast<float>(v(10));
        k.focal_slope = static_cast<float>(v(11));
        k.ring = rings(l);
    }
    return c;
}

/// Interleave four columns into one (n, 4) int64 array.
template <typename A, typename B, typename C, typename D>
Out<std::int64_t, 2> columns4(const A& a, const B& b, const C& c, const D& d) {
    const size_t n = a.size();
    std::vector<std::int64_t> out(n * 4);
    for (size_t i = 0; i < n; ++i) {
        out[4 * i] = a[i];
        out[4 * i + 1] = b[i];
        out[4 * i + 2] = c[i];
        out[4 * i + 3] = d[i];
    }
    return owned_array<nb::ndim<2>>(std::move(out), {n, 4});
}

PcapScanArrays scan_records(BytesIn buf, const tripod::PcapLayout& layout, std::size_t data_size,
                            std::uint32_t max_record_bytes) {
    tripod::PcapScan s;
    {
        nb::gil_scoped_release release;
        s = tripod::scan_pcap_records(buf.data(), buf.shape(0), layout, data_size,
                                      max_record_bytes);
    }
    PcapScanArrays r;
    r.consumed = s.consumed;
    r.records = s.records;
    r.oversize_bytes = s.oversize ? s.oversize_bytes : 0u;
    const size_t nd = s.data_t_ns.size();
    r.data = owned_array<nb::ndim<2>>(std::move(s.data), {nd, data_size});
    r.data_t_ns = owned_array(std::move(s.data_t_ns));
    r.data_port = owned_array(std::move(s.data_port));
    r.data_record = owned_array(std::move(s.data_record));
    r.other = columns4(s.other_t_ns, s.other_offset, s.other_length, s.other_port);
    r.slow = columns4(s.slow_t_ns, s.slow_offset, s.slow_length, s.slow_record);
    return r;
}

void bind_pcap_scan(nb::module_& m) {
    nb::class_<tripod::PcapLayout>(m, "_PcapLayout", "Layout of a classic pcap (its header)")
        .def(nb::init<>())
        .def_rw("big_endian", &tripod::PcapLayout::big_endian, "record headers big-endian")
        .def_rw("nanosecond", &tripod::PcapLayout::nanosecond, "fractions in ns, else us")
        .def_rw("linktype", &tripod::PcapLayout::linktype);
    nb::class_<PcapScanArrays>(m, "_PcapScan", "What one _scan_pcap_records call found")
        .def_ro("consumed", &PcapScanArrays::consumed, "bytes of the whole records scanned")
        .def_ro("records", &PcapScanArrays::records, "whole records scanned")
        .def_ro("oversize_bytes", &PcapScanArrays::oversize_bytes,
                "bytes claimed by the record that stopped the scan as corrupt, or 0")
        .def_ro("data", &PcapScanArrays::data, "(n, data_size) uint8 payloads of plain "
                "Ethernet/IPv4/UDP records", nb::rv_policy::reference)
        .def_ro("data_t_ns", &PcapScanArrays::data_t_ns, "(n,) int64 capture time [ns]", nb::rv_policy::reference)
        .def_ro("data_port", &PcapScanArrays::data_port, "(n,) uint16 UDP destination port", nb::rv_policy::reference)
        .def_ro("data_record", &PcapScanArrays::data_record, "(n,) int64 record index", nb::rv_policy::reference)
        .def_ro("other", &PcapScanArrays::other, "(k, 4) int64 [t_ns, payload offset, length, "
                "port] of other plain payloads", nb::rv_policy::reference)
        .def_ro("slow", &PcapScanArrays::slow, "(m, 4) int64 [t_ns, frame offset, length, "
                "record index] of records to parse in Python", nb::rv_policy::reference);
    m.def("_scan_pcap_records", &scan_records, nb::arg("buf"), nb::arg("layout"),
          nb::arg("data_size"), nb::arg("max_record_bytes"),
          "Scan the whole classic-pcap records at the start of buf (uint8) (private: use "
          "tripod_processor.io.pcap.PcapReader).");
}

DecodedChunk decode_chunk(const tripod::Vlp16Decoder& self, PacketsIn packets, I64In stamps_ns,
                          std::optional<I64In> seg_first_block, std::optional<I64In> seg_ref_ns,
                          bool with_time_s, int num_threads, std::uint8_t return_type_before) {
    const std::size_t n = packets.shape(0);
    if (stamps_ns.shape(0) != n)
        throw std::invalid_argument("stamps_ns must have one entry per packet");
    if (seg_first_block.has_value() != seg_ref_ns.has_value())
        throw std::invalid_argument("give both seg_first_block and seg_ref_ns, or neither");
    const std::int64_t* seg_b = nullptr;
    const std::int64_t* seg_r = nullptr;
    std::size_t n_seg = 0;
    if (seg_first_block) {
        if (seg_first_block->shape(0) != seg_ref_ns->shape(0))
            throw std::invalid_argument(
                "seg_first_block and seg_ref_ns must have the same length");
        n_seg = seg_first_block->shape(0);
        seg_b = seg_first_block->data();
        seg_r = seg_ref_ns->data();
    }
    tripod::Vlp16Batch b;
    {
        nb::gil_scoped_release release;
        b = self.decode(packets.data(), n, stamps_ns.data(), seg_b, seg_r, n_seg, with_time_s,
                        num_threads, return_type_before);
    }
    DecodedChunk r;
    const std::size_t np = b.num_points;
    r.points = owned_array<nb::ndim<2>>(PointBytes{std::move(b.points)},
                                        {np, sizeof(tripod::Vlp16Point)});
    if (with_time_s) {
        r.time_s = owned_array<nb::ndim<1>>(std::move(b.time_s), {np});
    } else {
        r.time_s = owned_array(std::vector<float>());
    }
    r.block_first_point = owned_array(std::move(b.block_first_point));
    std::vector<std::uint8_t> status(b.status.size());
    for (std::size_t k = 0; k < status.size(); ++k)
        status[k] = static_cast<std::uint8_t>(b.status[k]);
    r.status = owned_array(std::move(status));
    r.time_offset_clipped = b.time_offset_clipped;
    r.return_type_after = b.return_type_after;
    return r;
}

void bind_vlp16_decoder(nb::module_& m) {
    nb::class_<tripod::Vlp16DecoderConfig>(m, "_Vlp16DecoderConfig",
                                           "Filters of the batch decoder (velodyne-decoder's "
                                           "Config for the same purpose)")
        .def(nb::init<>())
        .def_rw("min_range_m", &tripod::Vlp16DecoderConfig::min_range_m,
                "returns nearer than this are dropped [m]")
        .def_rw("max_range_m", &tripod::Vlp16DecoderConfig::max_range_m,
                "returns farther than this are dropped [m]")
        .def_rw("min_angle_deg", &tripod::Vlp16DecoderConfig::min_angle_deg,
                "keep azimuths from here [deg] ...")
        .def_rw("max_angle_deg", &tripod::Vlp16DecoderConfig::max_angle_deg,
                "... clockwise to here [deg]; across 0 when min > max");
    nb::class_<DecodedChunk>(m, "_DecodedChunk", "What one _Vlp16Decoder.decode call gave")
        .def_ro("points", &DecodedChunk::points, "(M, 20) uint8 = POINT_DTYPE records", nb::rv_policy::reference)
        .def_ro("time_s", &DecodedChunk::time_s,
                "(M,) float32 velodyne-decoder time since packet 0 [s], or empty", nb::rv_policy::reference)
        .def_ro("block_first_point", &DecodedChunk::block_first_point,
                "(N*12+1,) int64 first point of each flat block", nb::rv_policy::reference)
        .def_ro("status", &DecodedChunk::status,
                "(N,) uint8 per packet: 0 ok, 1 bad block header (the blocks before it kept)", nb::rv_policy::reference)
        .def_ro("time_offset_clipped", &DecodedChunk::time_offset_clipped)
        .def_ro("return_type_after", &DecodedChunk::return_type_after,
                "pass it as return_type_before of the next chunk");
    nb::class_<tripod::Vlp16Decoder>(m, "_Vlp16Decoder",
                                     "Batch VLP-16 / Puck Hi-Res decoder equal to "
                                     "velodyne-decoder 3.1 (private: use tripod_processor.decode)")
        .def(
            "__init__",
            [](tripod::Vlp16Decoder* self, F64Table corrections, double distance_resolution_m,
               RingsIn rings, const tripod::Vlp16DecoderConfig& config) {
                new (self) tripod::Vlp16Decoder(
                    calibration_from(corrections, distance_resolution_m, rings), config);
            },
            nb::arg("corrections"), nb::arg("distance_resolution_m"), nb::arg("rings"),
            nb::arg("config"),
            "corrections: (16, 12) float64, per laser in firing order: rot_correction [rad], "
            "vert_correction [rad], dist_correction [m], two_pt_correction_available (0/1), "
            "dist_correction_x [m], dist_correction_y [m], vert_offset_correction [m], "
            "horiz_offset_correction [m], max_intensity, min_intensity, focal_distance, "
            "focal_slope. rings: (16,) uint8 rank of each laser by elevation.")
        .def("decode", &decode_chunk, nb::arg("packets"), nb::arg("stamps_ns"),
             nb::arg("seg_first_block") = nb::none(), nb::arg("seg_ref_ns") = nb::none(),
             nb::arg("with_time_s") = false, nb::arg("num_threads") = 0,
             nb::arg("return_type_before") = tripod::kReturnTypeUnknown,
             "Decode (N, 1206) uint8 packets stamped (N,) int64 [ns]; segments (frames) of "
             "the chunk: their first flat block (packet * 12 + block) and reference time [ns].");
}

}  // namespace

TRIPOD_BINDING(decode) {
    bind_pcap_scan(m);
    bind_vlp16_decoder(m);
}
