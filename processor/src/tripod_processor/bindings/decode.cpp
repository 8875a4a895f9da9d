// SPDX-License-Identifier: BSD-3-Clause
// Bindings: the batch VLP-16 decoder (tripod_core/velodyne_decoder.hpp). Conversions and
// docstrings only; one call per chunk of packets, the GIL released while it decodes.
#include <nanobind/stl/tuple.h>

#include "common.hpp"
#include "tripod_core/pcap_scan.hpp"
#include "tripod_core/velodyne_decoder.hpp"

namespace nb = nanobind;
using namespace tripod_bind;

namespace {

using PacketsIn =
    nb::ndarray<const std::uint8_t, nb::shape<-1, 1206>, nb::c_contig, nb::device::cpu>;
using I64In = nb::ndarray<const std::int64_t, nb::shape<-1>, nb::c_contig, nb::device::cpu>;
using F64Table = nb::ndarray<const double, nb::shape<16, 12>, nb::c_contig, nb::device::cpu>;
using U8Out = nb::ndarray<nb::numpy, std::uint8_t, nb::ndim<2>>;
using F32Out = nb::ndarray<nb::numpy, float, nb::ndim<1>>;
using I64Out = nb::ndarray<nb::numpy, std::int64_t, nb::ndim<1>>;

template <typename T>
nb::capsule owner_of(T* p) {
    return nb::capsule(p, [](void* q) noexcept { delete[] static_cast<T*>(q); });
}

/// Columns of the (16, 12) calibration table, in this order (velodyne-decoder's LaserCorrection).
tripod::Vlp16Calibration calibration_from(const F64Table& t, double distance_resolution_m,
                                          nb::ndarray<const std::uint8_t, nb::shape<16>,
                                                      nb::c_contig, nb::device::cpu> rings) {
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

/// Move a vector into a numpy array owned by a capsule (no copy).
template <typename T>
nb::ndarray<nb::numpy, T> vector_to_numpy(std::vector<T>&& v, std::initializer_list<size_t> shape) {
    auto* heap = new std::vector<T>(std::move(v));
    nb::capsule owner(heap, [](void* p) noexcept { delete static_cast<std::vector<T>*>(p); });
    return nb::ndarray<nb::numpy, T>(heap->data(), shape.size(), shape.begin(), owner);
}

}  // namespace

TRIPOD_BINDING(decode) {
    m.def(
        "_scan_pcap_records",
        [](nb::ndarray<const std::uint8_t, nb::ndim<1>, nb::c_contig, nb::device::cpu> buf,
           bool big_endian, bool nanosecond, std::uint32_t linktype, std::size_t data_size,
           std::uint32_t max_record_bytes) {
            tripod::PcapLayout layout{big_endian, nanosecond, linktype};
            tripod::PcapScan s;
            {
                nb::gil_scoped_release release;
                s = tripod::scan_pcap_records(buf.data(), buf.shape(0), layout, data_size,
                                              max_record_bytes);
            }
            const size_t nd = s.data_t_ns.size(), no = s.other_t_ns.size(),
                         ns = s.slow_t_ns.size();
            std::vector<std::int64_t> other(no * 4), slow(ns * 4);
            for (size_t i = 0; i < no; ++i) {
                other[4 * i] = s.other_t_ns[i];
                other[4 * i + 1] = s.other_offset[i];
                other[4 * i + 2] = s.other_length[i];
                other[4 * i + 3] = s.other_port[i];
            }
            for (size_t i = 0; i < ns; ++i) {
                slow[4 * i] = s.slow_t_ns[i];
                slow[4 * i + 1] = s.slow_offset[i];
                slow[4 * i + 2] = s.slow_length[i];
                slow[4 * i + 3] = s.slow_record[i];
            }
            return nb::make_tuple(
                s.consumed, s.records, s.oversize ? s.oversize_bytes : 0u,
                vector_to_numpy(std::move(s.data), {nd, data_size}),
                vector_to_numpy(std::move(s.data_t_ns), {nd}),
                vector_to_numpy(std::move(s.data_port), {nd}),
                vector_to_numpy(std::move(s.data_record), {nd}),
                vector_to_numpy(std::move(other), {no, 4}),
                vector_to_numpy(std::move(slow), {ns, 4}));
        },
        nb::arg("buf"), nb::arg("big_endian"), nb::arg("nanosecond"), nb::arg("linktype"),
        nb::arg("data_size"), nb::arg("max_record_bytes"),
        "Scan whole classic-pcap records at the start of buf (uint8). Returns (consumed bytes, "
        "records, oversize record bytes or 0, data (n, data_size) uint8 payloads of plain "
        "Ethernet/IPv4/UDP records, data_t_ns (n,) int64, data_port (n,) uint16, data_record "
        "(n,) int64 record index, other (k, 4) int64 [t_ns, payload offset, length, port] of "
        "other plain payloads, slow (m, 4) int64 [t_ns, frame offset, length, record index] of "
        "records to parse in Python).");

    nb::class_<tripod::Vlp16Decoder>(m, "_Vlp16Decoder",
                                     "Batch VLP-16 / Puck Hi-Res decoder equal to "
                                     "velodyne-decoder 3.1 (private: use tripod_processor.decode)")
        .def(
            "__init__",
            [](tripod::Vlp16Decoder* self, F64Table corrections, double distance_resolution_m,
               nb::ndarray<const std::uint8_t, nb::shape<16>, nb::c_contig, nb::device::cpu> rings,
               double min_range_m, double max_range_m, double min_angle_deg,
               double max_angle_deg) {
                tripod::Vlp16DecoderConfig cfg;
                cfg.min_range_m = static_cast<float>(min_range_m);
                cfg.max_range_m = static_cast<float>(max_range_m);
                cfg.min_angle_deg = min_angle_deg;
                cfg.max_angle_deg = max_angle_deg;
                new (self) tripod::Vlp16Decoder(
                    calibration_from(corrections, distance_resolution_m, rings), cfg);
            },
            nb::arg("corrections"), nb::arg("distance_resolution_m"), nb::arg("rings"),
            nb::arg("min_range_m"), nb::arg("max_range_m"), nb::arg("min_angle_deg") = 0.0,
            nb::arg("max_angle_deg") = 360.0,
            "corrections: (16, 12) float64, per laser in firing order: rot_correction [rad], "
            "vert_correction [rad], dist_correction [m], two_pt_correction_available (0/1), "
            "dist_correction_x [m], dist_correction_y [m], vert_offset_correction [m], "
            "horiz_offset_correction [m], max_intensity, min_intensity, focal_distance, "
            "focal_slope. rings: (16,) uint8 rank of each laser by elevation.")
        .def(
            "decode",
            [](const tripod::Vlp16Decoder& self, PacketsIn packets, I64In stamps_ns,
               nb::object seg_first_block, nb::object seg_ref_ns, bool with_time_s,
               int num_threads, std::uint8_t return_type_before) {
                const std::size_t n = packets.shape(0);
                if (stamps_ns.shape(0) != n)
                    throw std::invalid_argument("stamps_ns must have one entry per packet");
                const std::int64_t* seg_b = nullptr;
                const std::int64_t* seg_r = nullptr;
                std::size_t n_seg = 0;
                I64In sb, sr;
                if (!seg_first_block.is_none()) {
                    sb = nb::cast<I64In>(seg_first_block);
                    sr = nb::cast<I64In>(seg_ref_ns);
                    if (sb.shape(0) != sr.shape(0))
                        throw std::invalid_argument(
                            "seg_first_block and seg_ref_ns must have the same length");
                    n_seg = sb.shape(0);
                    seg_b = sb.data();
                    seg_r = sr.data();
                }
                tripod::Vlp16Batch b;
                {
                    nb::gil_scoped_release release;
                    b = self.decode(packets.data(), n, stamps_ns.data(), seg_b, seg_r, n_seg,
                                    with_time_s, num_threads, return_type_before);
                }
                const std::size_t np = b.num_points;
                auto* pts = reinterpret_cast<std::uint8_t*>(b.points.release());
                U8Out points(pts, {np, sizeof(tripod::Vlp16Point)},
                             owner_of(reinterpret_cast<tripod::Vlp16Point*>(pts)));
                F32Out time_s;
                if (with_time_s) {
                    float* t = b.time_s.release();
                    time_s = F32Out(t, {np}, owner_of(t));
                } else {
                    float* t = new float[0];
                    time_s = F32Out(t, {0}, owner_of(t));
                }
                auto* bf = new std::int64_t[b.block_first_point.size()];
                std::copy(b.block_first_point.begin(), b.block_first_point.end(), bf);
                I64Out block_first(bf, {b.block_first_point.size()}, owner_of(bf));
                auto* st = new std::uint8_t[n ? n : 1];
                for (std::size_t k = 0; k < n; ++k) st[k] = static_cast<std::uint8_t>(b.status[k]);
                nb::ndarray<nb::numpy, std::uint8_t, nb::ndim<1>> status(st, {n}, owner_of(st));
                return nb::make_tuple(points, time_s, block_first, status,
                                      b.time_offset_clipped, b.return_type_after);
            },
            nb::arg("packets"), nb::arg("stamps_ns"), nb::arg("seg_first_block") = nb::none(),
            nb::arg("seg_ref_ns") = nb::none(), nb::arg("with_time_s") = false,
            nb::arg("num_threads") = 0,
            nb::arg("return_type_before") = tripod::kReturnTypeUnknown,
            "Decode (N, 1206) uint8 packets stamped (N,) int64 [ns]. Returns (points (M, 20) "
            "uint8 = POINT_DTYPE records, time_s (M,) float32 velodyne-decoder time since "
            "packet 0 [s] or empty, block_first_point (N*12+1,) int64, status (N,) uint8: "
            "0 ok, 1 bad block header (the blocks before it kept), "
            "time_offset_clipped, return_type_after (pass it as return_type_before of the next "
            "chunk)).");
}
