// SPDX-License-Identifier: BSD-3-Clause
// Batch VLP-16 decoder. Every float operation below follows velodyne-decoder 3.x
// (src/packet_decoder.cpp: buildTimings, setupSinCosCache, setupCalibrationCache,
// unpack_16_32_beam, unpackPointDual, unpackPoint; time_conversion.cpp) in the same order and
// precision, so that the results are bit-equal to the 3.1 wheel; this file is compiled with
// -ffp-contract=off for the same reason (a fused multiply-add would round differently). Where
// 3.1 differs from the 3.x source at hand (the full calibration model), its behaviour was
// measured term by term and is noted there.
#include "tripod_core/vlp16_decoder.hpp"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <stdexcept>

namespace tripod {
namespace {

constexpr int kBlockSize = 100;  // flag (2) + azimuth (2) + 32 x (distance 2, intensity 1)
constexpr std::uint8_t kFlag0 = 0xFF, kFlag1 = 0xEE;  // block flag of lasers 0..31 (bank 0)
constexpr std::uint8_t kStrongestReturn = 0x37, kLastReturn = 0x38, kDualReturn = 0x39;
constexpr std::uint8_t kStrongest = 1, kLast = 2, kBoth = 3;  // velodyne_decoder.ReturnMode
constexpr std::size_t kReturnModeOffset = 1204;
constexpr int kRotationMaxUnits = 36000;    // [0.01 deg]
constexpr float kRotationResolution = 0.01f;  // [deg]

inline std::uint16_t read_u16(const std::uint8_t* p) {
    return static_cast<std::uint16_t>(p[0] | (p[1] << 8));
}
inline std::uint32_t read_u32(const std::uint8_t* p) {
    return static_cast<std::uint32_t>(p[0]) | (static_cast<std::uint32_t>(p[1]) << 8) |
           (static_cast<std::uint32_t>(p[2]) << 16) | (static_cast<std::uint32_t>(p[3]) << 24);
}

// velodyne-decoder's TimePair(host, data).device (time_conversion.cpp getPacketTimestamp): the
// packet's microseconds past the hour put on the host time's hour, the nearer of three hours
double device_time_s(std::uint32_t usec_since_toh, double reference_time) {
    const int hour_to_sec = 3600;
    const std::uint32_t cur_hour = (std::uint32_t)std::floor(reference_time) / hour_to_sec;
    const double packet_time = cur_hour * hour_to_sec + usec_since_toh * 1e-6;
    if (reference_time > 0) {
        if (packet_time > reference_time + 1800.0) return packet_time - 3600.0;
        if (packet_time < reference_time - 1800.0) return packet_time + 3600.0;
    }
    return packet_time;
}
constexpr std::size_t kStampOffset = 1200;  // uint32 microseconds past the hour

// velodyne-decoder's wrap(int) and wrap(float): note the float version adds 36000 in float
inline std::uint16_t wrap_int(int azimuth) {
    return static_cast<std::uint16_t>((azimuth + 36000) % 36000);
}
inline std::uint16_t wrap_float(float azimuth) {
    // std::lround(azimuth + 36000) without the libm call: the float sum is >= 0 here (block
    // azimuth >= 0, rotation rate >= 0), and for a float v >= 0, (double)v + 0.5 is exact, so
    // truncating it rounds half away from zero exactly as lround does
    const float v = azimuth + 36000;
    return static_cast<std::uint16_t>(static_cast<long>(static_cast<double>(v) + 0.5) % 36000);
}

template <typename T>
constexpr T sqr(T v) {
    return v * v;
}

}  // namespace

bool Vlp16Calibration::is_advanced() const {
    for (const auto& c : lasers) {
        if (c.dist_correction != 0 || c.two_pt_correction_available || c.dist_correction_x != 0 ||
            c.dist_correction_y != 0 || c.vert_offset_correction != 0 ||
            c.horiz_offset_correction != 0 || c.max_intensity != 255 || c.min_intensity != 0 ||
            c.focal_distance != 0 || c.focal_slope != 0)
            return true;
    }
    return false;
}

Vlp16Decoder::Vlp16Decoder(const Vlp16Calibration& calibration, const Vlp16DecoderConfig& config)
    : calibration_(calibration), config_(config), advanced_(calibration.is_advanced()) {
    if (!(config.min_range_m <= config.max_range_m))
        throw std::invalid_argument("min_range_m must not exceed max_range_m");
    min_azimuth_ = static_cast<int>(
        std::lround(std::fmod(std::fmod(config.min_angle_deg, 360) + 360, 360) * 100));
    max_azimuth_ = static_cast<int>(
        std::lround(std::fmod(std::fmod(config.max_angle_deg, 360) + 360, 360) * 100));
    if (min_azimuth_ == max_azimuth_) {
        min_azimuth_ = 0;
        max_azimuth_ = 36000;
    }
    // sin/cos of every azimuth step (setupSinCosCache)
    cos_rot_table_.resize(kRotationMaxUnits);
    sin_rot_table_.resize(kRotationMaxUnits);
    constexpr float deg2rad = M_PI / 180.f;
    for (std::uint16_t i = 0; i < kRotationMaxUnits; ++i) {
        float rotation = kRotationResolution * i * deg2rad;
        cos_rot_table_[i] = cosf(rotation);
        sin_rot_table_[i] = sinf(rotation);
    }
    // per-laser angle caches (setupCalibrationCache)
    for (int l = 0; l < 16; ++l) {
        const auto& c = calibration_.lasers[l];
        cos_rot_corr_[l] = cosf(c.rot_correction);
        sin_rot_corr_[l] = sinf(c.rot_correction);
        cos_vert_[l] = cosf(c.vert_correction);
        sin_vert_[l] = sinf(c.vert_correction);
    }
    // VLP-16 firing timing (VLP-16 manual): 2.304 us per laser, 55.296 us per firing sequence,
    // two sequences per block (buildTimings)
    const double full_firing_cycle = 55.296 * 1e-6;  // [s]
    const double single_firing = 2.304 * 1e-6;      // [s]
    for (int i = 0; i < 12; ++i) {
        for (int j = 0; j < 32; ++j) {
            std::uint16_t block_index = static_cast<std::uint16_t>(2 * i + j / 16);
            std::uint16_t point_index = static_cast<std::uint16_t>(j % 16);
            timing_s_[i][j] =
                (float)(full_firing_cycle * block_index + single_firing * point_index);
            timing_ns_[i][j] = 55296 * block_index + 2304 * point_index;
        }
    }
}

bool Vlp16Decoder::azimuth_in_range(std::uint16_t azimuth) const {
    if (min_azimuth_ <= max_azimuth_) return azimuth >= min_azimuth_ && azimuth <= max_azimuth_;
    // a range across 0 (e.g. 270 to 90, the front half): the ROS velodyne driver's rule.
    // velodyne-decoder 3.1 keeps [max, min] here instead (as if the bounds were swapped), so
    // tripod.decode refuses such a range on its velodyne_decoder path.
    return azimuth >= min_azimuth_ || azimuth <= max_azimuth_;
}

/// One return's x, y, z [m] and calibrated intensity (velodyne-decoder's unpackPoint; the
/// full correction model when the calibration is "advanced"); false when the range filter
/// drops it.
bool Vlp16Decoder::point_of(int laser, std::uint16_t azimuth, const std::uint8_t* m, float& x,
                            float& y, float& z, float& intensity) const {
    const std::uint16_t raw_distance = read_u16(m);
    const std::uint8_t raw_intensity = m[2];
    float distance = raw_distance * calibration_.distance_resolution_m;
    const float cos_vert_angle = cos_vert_[laser];
    const float sin_vert_angle = sin_vert_[laser];
    const float cos_rot_correction = cos_rot_corr_[laser];
    const float sin_rot_correction = sin_rot_corr_[laser];
    // cos(a-b) = cos(a)*cos(b) + sin(a)*sin(b); sin(a-b) = sin(a)*cos(b) - cos(a)*sin(b)
    const float cos_rot_angle = cos_rot_table_[azimuth] * cos_rot_correction +
                                sin_rot_table_[azimuth] * sin_rot_correction;
    const float sin_rot_angle = sin_rot_table_[azimuth] * cos_rot_correction -
                                cos_rot_table_[azimuth] * sin_rot_correction;
    if (!advanced_) {
        if (!(distance >= config_.min_range_m && distance <= config_.max_range_m)) return false;
        const float xy_distance = distance * cos_vert_angle;
        x = xy_distance * cos_rot_angle;  // ROS frame: x forward, y left, z up
        y = -xy_distance * sin_rot_angle;
        z = distance * sin_vert_angle;
        intensity = (float)raw_intensity;
    } else {
        // velodyne-decoder 3.1's full model (its source is not at hand: the terms below were
        // measured against it one at a time, see tests/processor/test_native_decoder.py)
        const auto& c = calibration_.lasers[laser];
        distance += c.dist_correction;
        if (!(distance >= config_.min_range_m && distance <= config_.max_range_m))
            return false;
        const float horiz_offset = c.horiz_offset_correction;
        const float vert_offset = c.vert_offset_correction;
        // two-point correction: the distance correction interpolated between the near (x:
        // 2.4 m, y: 1.93 m) and far (25.04 m) calibration points by the point's |x| and |y|
        // in the sensor frame; 3.1 adds the whole correction to the raw distance and takes
        // their mean for z (measured: this matches 3.1 to one float32 ulp on a few points
        // in a thousand, exactly on the rest; the default VLP-16 tables have no two-point
        // values)
        const float raw_m = raw_distance * calibration_.distance_resolution_m;
        float distance_x = distance, distance_y = distance, distance_z = distance;
        if (c.two_pt_correction_available) {
            const float xy_distance = distance * cos_vert_angle;
            const float xx = std::abs(xy_distance * sin_rot_angle);
            const float yy = std::abs(xy_distance * cos_rot_angle);
            const float corr_x = (c.dist_correction - c.dist_correction_x) * (xx - 2.4f) /
                                     (25.04f - 2.4f) +
                                 c.dist_correction_x;
            const float corr_y = (c.dist_correction - c.dist_correction_y) * (yy - 1.93f) /
                                     (25.04f - 1.93f) +
                                 c.dist_correction_y;
            distance_x = raw_m + corr_x;
            distance_y = raw_m + corr_y;
            distance_z = raw_m + (corr_x + corr_y) / 2;
        }
        float xy_distance = distance_x * cos_vert_angle;
        const float xs = xy_distance * sin_rot_angle - horiz_offset * cos_rot_angle;
        xy_distance = distance_y * cos_vert_angle;
        const float ys = xy_distance * cos_rot_angle + horiz_offset * sin_rot_angle;
        // the VLP-16 manual's vertical offset: z only
        z = distance_z * sin_vert_angle + vert_offset;
        x = ys;  // the Velodyne manual's frame turned to ROS's
        y = -xs;
        const float min_intensity = (float)c.min_intensity;
        const float max_intensity = (float)c.max_intensity;
        // focal distance in the calibration's unit, the formula's in 1/100 of it
        const float focal_offset = sqr(1 - c.focal_distance * 100 / 13100.f);
        const float raw_intensity_f = raw_intensity;
        const float raw_distance_f = raw_distance;
        intensity = raw_intensity_f +
                    256 * c.focal_slope *
                        std::abs(focal_offset - sqr(1 - raw_distance_f / 65535.f));
        intensity = (intensity < min_intensity) ? min_intensity : intensity;
        intensity = (intensity > max_intensity) ? max_intensity : intensity;
    }
    return true;
}

PacketStatus Vlp16Decoder::decode_packet(const std::uint8_t* raw, std::int64_t stamp_ns,
                                         float rel_packet_stamp_s, std::uint8_t single_type,
                                         std::int64_t flat_block0,
                                         const std::int64_t* seg_first_block,
                                         const std::int64_t* seg_ref_ns, std::size_t n_segments,
                                         PacketOut out, int& n_points, bool& clipped) const {
    n_points = 0;
    std::fill(out.block_counts, out.block_counts + kBlocksPerPacket, std::uint16_t{0});
    // (any block azimuth is safe: the rotation rate is never negative, so the interpolated
    // azimuth wraps into [0, 36000) before it indexes the tables; sensors do send 36000)
    const std::uint8_t return_mode = raw[kReturnModeOffset];
    const bool dual_return = return_mode == kDualReturn;
    // mean rotation rate of the packet [0.01 deg / s]
    const std::uint16_t azimuth_diff =
        wrap_int((int)read_u16(raw + 11 * kBlockSize + 2) - (int)read_u16(raw + 2));
    const float duration = timing_s_[dual_return ? 11 / 2 : 11][0] - timing_s_[0][0];
    const float rotation_rate = (float)azimuth_diff / duration;

    // segment (frame) of the packet's first block; advanced as the blocks go
    std::size_t seg = 0;
    if (n_segments) {
        seg = static_cast<std::size_t>(
            std::upper_bound(seg_first_block, seg_first_block + n_segments, flat_block0) -
            seg_first_block);
        seg = seg ? seg - 1 : 0;
    }
    const std::int64_t default_ref = seg_ref_ns[0];  // the batch's single segment

    auto emit = [&](int laser, std::uint16_t azimuth, float time_s, std::int32_t t_ns_in_packet,
                    std::int64_t ref_ns, const std::uint8_t* m, std::uint8_t rtype,
                    int block) {
        float x, y, z, intensity;
        if (!point_of(laser, azimuth, m, x, y, z, intensity)) return;  // out of range
        const std::int64_t off = stamp_ns + t_ns_in_packet - ref_ns;
        std::int32_t off32;
        if (off > std::numeric_limits<std::int32_t>::max()) {
            off32 = std::numeric_limits<std::int32_t>::max();
            clipped = true;
        } else if (off < -std::numeric_limits<std::int32_t>::max()) {
            off32 = -std::numeric_limits<std::int32_t>::max();
            clipped = true;
        } else {
            off32 = static_cast<std::int32_t>(off);
        }
        Vlp16Point& p = out.points[n_points];
        p.x = x;
        p.y = y;
        p.z = z;
        p.time_offset_ns = off32;
        // a float->uint8 cast truncates like numpy's; the clamp only matters for calibrations
        // whose max_intensity exceeds 255
        p.intensity = static_cast<std::uint8_t>(std::min(std::max(intensity, 0.f), 255.f));
        p.ring = calibration_.lasers[laser].ring;
        p.laser = static_cast<std::uint8_t>(laser);
        p.return_type = rtype;
        if (out.time_s) out.time_s[n_points] = time_s;
        ++n_points;
        ++out.block_counts[block];
    };

    const int block_step = dual_return ? 2 : 1;
    for (int i = 0; i < kBlocksPerPacket; i += block_step) {
        const std::uint8_t* block = raw + i * kBlockSize;
        if (block[0] != kFlag0 || block[1] != kFlag1)
            return PacketStatus::bad_block_header;  // velodyne-decoder: skip the rest
        const std::uint16_t block_azimuth = read_u16(block + 2);
        const std::int64_t flat = flat_block0 + i;
        while (n_segments && seg + 1 < n_segments && seg_first_block[seg + 1] <= flat) ++seg;
        const std::int64_t ref_ns = n_segments ? seg_ref_ns[seg] : default_ref;
        const int ti = dual_return ? i / 2 : i;  // timing row
        const float t0 = timing_s_[ti][0];
        for (int j = 0; j < 32; ++j) {
            const std::uint8_t* m = block + 4 + 3 * j;
            const std::uint8_t* m2 = dual_return ? block + kBlockSize + 4 + 3 * j : nullptr;
            const std::uint16_t d1 = read_u16(m);
            const std::uint16_t d2 = dual_return ? read_u16(m2) : 0;
            if (d1 == 0 && d2 == 0) continue;
            const float time = timing_s_[ti][j];
            const float dt = time - t0;
            const std::uint16_t azimuth = wrap_float(block_azimuth + rotation_rate * dt);
            if (!azimuth_in_range(azimuth)) continue;
            const float full_time = rel_packet_stamp_s + time;
            const int laser = j >= 16 ? j - 16 : j;
            const std::int32_t t_ns = timing_ns_[ti][j];
            if (!dual_return) {
                emit(laser, azimuth, full_time, t_ns, ref_ns, m, single_type, i);
            } else if (d1 == d2) {  // block i: last return, block i + 1: strongest
                emit(laser, azimuth, full_time, t_ns, ref_ns, m2, kBoth, i);
            } else {
                if (d1 > 0) emit(laser, azimuth, full_time, t_ns, ref_ns, m, kLast, i);
                if (d2 > 0) emit(laser, azimuth, full_time, t_ns, ref_ns, m2, kStrongest, i);
            }
        }
    }
    return PacketStatus::ok;
}

Vlp16Batch Vlp16Decoder::decode(const std::uint8_t* packets, std::size_t n_packets,
                                const std::int64_t* stamps_ns, const std::int64_t* seg_first_block,
                                const std::int64_t* seg_ref_ns, std::size_t n_segments,
                                bool with_time_s, int num_threads,
                                std::uint8_t return_type_before) const {
    Vlp16Batch out;
    out.status.assign(n_packets, PacketStatus::ok);
    out.block_first_point.assign(n_packets * kBlocksPerPacket + 1, 0);
    out.return_type_after = return_type_before;
    if (n_packets == 0) return out;
    // Return type of single-return points: velodyne-decoder keeps the last return mode it
    // recognised (0x37 strongest, 0x38 last, 0x39 dual) and labels a packet with another mode
    // byte after it; a sequential scan, so that the packets can then go in parallel
    std::vector<std::uint8_t> single_type(n_packets);
    std::uint8_t state = return_type_before;
    for (std::size_t k = 0; k < n_packets; ++k) {
        const std::uint8_t mode = packets[k * kVelodynePacketSize + kReturnModeOffset];
        if (mode == kStrongestReturn) state = kStrongest;
        else if (mode == kLastReturn) state = kLast;
        else if (mode == kDualReturn) state = kBoth;
        single_type[k] = state;
    }
    out.return_type_after = state;
    // Each packet decodes into its own slot of kMaxPointsPerPacket; each thread then packs its
    // slots to the front of its range, and the ranges are moved together. new T[] of a trivial
    // type leaves the memory untouched: no page is written twice.
    const std::size_t capacity = n_packets * kMaxPointsPerPacket;
    out.points.reset(new Vlp16Point[capacity]);
    if (with_time_s) out.time_s.reset(new float[capacity]);
    std::vector<std::uint16_t> block_counts(n_packets * kBlocksPerPacket, 0);
    if (num_threads <= 0) num_threads = omp_get_max_threads();
    num_threads = static_cast<int>(
        std::max<std::size_t>(1, std::min<std::size_t>(num_threads, (n_packets + 15) / 16)));
    std::vector<std::size_t> thread_count(num_threads, 0), thread_begin(num_threads, 0);
    bool clipped_any = false;
    // velodyne-decoder is given the stamps as host seconds (double) and times its points from
    // the device time it derives from them: float seconds since packet 0's device time
    auto device_s = [&](std::size_t k) {
        return device_time_s(read_u32(packets + k * kVelodynePacketSize + kStampOffset),
                             (double)stamps_ns[k] * 1e-9);
    };
    const double stamp0_s = with_time_s ? device_s(0) : 0.0;
    // without segments: one, referenced to packet 0's stamp
    const std::int64_t single_ref = stamps_ns[0];
    const std::int64_t* refs = n_segments ? seg_ref_ns : &single_ref;

#pragma omp parallel num_threads(num_threads) reduction(|| : clipped_any)
    {
        const int t = omp_get_thread_num();
        const int nt = omp_get_num_threads();
        const std::size_t k0 = n_packets * t / nt, k1 = n_packets * (t + 1) / nt;
        std::size_t write = k0 * kMaxPointsPerPacket;
        thread_begin[t] = write;
        bool clipped = false;
        for (std::size_t k = k0; k < k1; ++k) {
            const float rel = with_time_s ? (float)(device_s(k) - stamp0_s) : 0.f;
            PacketOut po{out.points.get() + write,
                         with_time_s ? out.time_s.get() + write : nullptr,
                         block_counts.data() + k * kBlocksPerPacket};
            int n = 0;
            out.status[k] = decode_packet(packets + k * kVelodynePacketSize, stamps_ns[k], rel,
                                          single_type[k],
                                          static_cast<std::int64_t>(k) * kBlocksPerPacket,
                                          seg_first_block, refs, n_segments, po, n, clipped);
            write += static_cast<std::size_t>(n);
        }
        thread_count[t] = write - thread_begin[t];
        clipped_any = clipped_any || clipped;
    }
    // move the ranges of threads 1.. behind the one before (thread 0's is in place)
    std::size_t total = thread_count[0];
    for (int t = 1; t < num_threads; ++t) {
        if (thread_count[t] && thread_begin[t] != total) {
            std::memmove(out.points.get() + total, out.points.get() + thread_begin[t],
                         thread_count[t] * sizeof(Vlp16Point));
            if (with_time_s)
                std::memmove(out.time_s.get() + total, out.time_s.get() + thread_begin[t],
                             thread_count[t] * sizeof(float));
        }
        total += thread_count[t];
    }
    out.num_points = total;
    out.time_offset_clipped = clipped_any;
    if (total < capacity / 2) {
        // sparse packets (many empty returns): give back the unused room, since slices of the
        // points (whole frames) may outlive the call
        std::unique_ptr<Vlp16Point[]> exact(new Vlp16Point[total ? total : 1]);
        std::memcpy(exact.get(), out.points.get(), total * sizeof(Vlp16Point));
        out.points = std::move(exact);
        if (with_time_s) {
            std::unique_ptr<float[]> t(new float[total ? total : 1]);
            std::memcpy(t.get(), out.time_s.get(), total * sizeof(float));
            out.time_s = std::move(t);
        }
    }
    std::int64_t acc = 0;
    for (std::size_t b = 0; b < block_counts.size(); ++b) {
        out.block_first_point[b] = acc;
        acc += block_counts[b];
    }
    out.block_first_point.back() = acc;
    return out;
}

}  // namespace tripod
