// SPDX-License-Identifier: BSD-3-Clause
// Batch VLP-16 / Puck Hi-Res packet decoder, point for point equal to velodyne-decoder 3.1.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <vector>

namespace tripod {

/// Size of a Velodyne data packet's UDP payload [bytes].
constexpr std::size_t kVelodynePacketSize = 1206;
/// Data blocks per packet.
constexpr int kBlocksPerPacket = 12;
/// Most points one VLP-16 packet can give (12 blocks x 32 returns, also in dual return).
constexpr int kMaxPointsPerPacket = 384;

/// One laser's calibration, as velodyne-decoder's `LaserCorrection` holds it.
struct LaserCorrection {
    float rot_correction = 0;           ///< [rad]
    float vert_correction = 0;          ///< [rad]
    float dist_correction = 0;          ///< [m]
    bool two_pt_correction_available = false;
    float dist_correction_x = 0;        ///< [m]
    float dist_correction_y = 0;        ///< [m]
    float vert_offset_correction = 0;   ///< [m]
    float horiz_offset_correction = 0;  ///< [m]
    int max_intensity = 255;
    int min_intensity = 0;
    float focal_distance = 0;
    float focal_slope = 0;
    std::uint8_t ring = 0;  ///< rank by vertical angle, 0 = lowest
};

/// Calibration of a 16-laser sensor; lasers in firing (channel) order.
struct Vlp16Calibration {
    std::array<LaserCorrection, 16> lasers{};
    float distance_resolution_m = 0.002f;  ///< [m] per distance unit

    /// velodyne-decoder's rule: anything besides the two angles is "advanced" and switches to
    /// the full correction model (distance and offset corrections, intensity calibration).
    bool is_advanced() const;
};

/// Settings that velodyne-decoder's `Config` has for the same purpose.
struct Vlp16DecoderConfig {
    float min_range_m = 0.1f;   ///< returns nearer than this are dropped [m]
    float max_range_m = 200.f;  ///< returns farther than this are dropped [m]
    /// keep azimuths from min_angle clockwise to max_angle [deg] (the sensor's azimuth: 0 along
    /// +x, 90 along -y); a range across 0 when min > max (the ROS driver's rule;
    /// velodyne-decoder 3.1 keeps [max, min] then); equal bounds keep everything
    double min_angle_deg = 0;
    double max_angle_deg = 360;
};

/// One decoded point; 20 bytes, the layout of tripod_processor.decode.POINT_DTYPE.
struct Vlp16Point {
    float x, y, z;               ///< [m], sensor frame: x forward, y left, z up (REP-103)
    std::int32_t time_offset_ns; ///< firing time minus the point's segment reference [ns]
    std::uint8_t intensity;      ///< calibrated reflectivity 0..255
    std::uint8_t ring;           ///< laser rank by elevation, 0 = lowest
    std::uint8_t laser;          ///< laser in firing order (the packet's channel)
    std::uint8_t return_type;    ///< 1 strongest, 2 last, 3 both (velodyne_decoder.ReturnMode)
};
static_assert(sizeof(Vlp16Point) == 20, "Vlp16Point must be packed to 20 bytes");

/// Return type velodyne-decoder 3.1 gives single-return points before it has seen a packet
/// with a known return mode byte (measured: 63).
constexpr std::uint8_t kReturnTypeUnknown = 63;

/// What became of one packet of a batch.
enum class PacketStatus : std::uint8_t {
    ok = 0,
    bad_block_header = 1,  ///< a block without the 0xFFEE flag: the blocks before it are kept,
                           ///< as velodyne-decoder does
};

/// Result of Vlp16Decoder::decode. Points come in packet, block, firing order.
struct Vlp16Batch {
    std::unique_ptr<Vlp16Point[]> points;  ///< num_points valid entries (room for at most 2x)
    std::size_t num_points = 0;
    std::unique_ptr<float[]> time_s;       ///< velodyne-decoder's float time, when asked
    /// (n_packets * 12 + 1) first point of each flat block index; dual-return points belong to
    /// the even block of their pair. Points of block b: [block_first_point[b], [b + 1]).
    std::vector<std::int64_t> block_first_point;
    std::vector<PacketStatus> status;      ///< one per packet
    bool time_offset_clipped = false;      ///< a time offset did not fit in int32
    std::uint8_t return_type_after = kReturnTypeUnknown;  ///< state after the last packet
};

/// Decoder of VLP-16 / Puck Hi-Res data packets, many at a time.
///
/// It replicates velodyne-decoder 3.1's `PacketDecoder::unpack` for the 16-laser models
/// (`unpack_16_32_beam`, `unpackPointDual`, `unpackPoint`) operation for operation in float32,
/// so that x, y, z, the float time, intensity, ring, return type, the order of the points and
/// the returns it drops are the same: per-laser azimuth interpolated by firing time from the
/// packet's mean rotation rate (first to last block), sin/cos tables in 0.01 deg steps, the
/// range filter on the (corrected) distance, the azimuth filter, dual-return pairs giving one
/// "both" point when the two distances are equal, single-return points typed by the last known
/// return mode. The one known difference: with a two-point distance correction (an "advanced"
/// calibration term no VLP-16 table has) a few points in a thousand differ by one float32 ulp.
/// velodyne-decoder's `column` field is not produced. Packets are independent once the
/// return-mode state is known, so a batch is decoded in parallel (OpenMP).
class Vlp16Decoder {
public:
    Vlp16Decoder(const Vlp16Calibration& calibration, const Vlp16DecoderConfig& config);

    /// Decode `n_packets` packets of `kVelodynePacketSize` bytes each, back to back.
    ///
    /// @param packets        n_packets x 1206 bytes
    /// @param stamps_ns      n_packets packet stamps [ns] (any clock; the lidar clock in tripod)
    /// @param seg_first_block, seg_ref_ns  n_segments sorted flat block indices (packet * 12 +
    ///                       block) where a segment (frame) starts, and its reference time [ns]:
    ///                       time_offset_ns = stamp + firing offset - reference of the point's
    ///                       segment. With n_segments = 0 the reference is stamps_ns[0]. Blocks
    ///                       before seg_first_block[0] use seg_ref_ns[0].
    /// @param with_time_s    also give velodyne-decoder's float time [s] since packet 0:
    ///                       (float)(device_k - device_0) + (float)firing offset, where
    ///                       device_k is the packet's time past the hour put on the hour of
    ///                       its stamp (stamps_ns * 1e-9 s), as velodyne-decoder's TimePair
    /// @param num_threads    0 = all available
    /// @param return_type_before  return type of single-return packets whose mode byte is not
    ///                       a known one: the type of the last known mode before them (pass the
    ///                       previous batch's return_type_after to continue a stream)
    Vlp16Batch decode(const std::uint8_t* packets, std::size_t n_packets,
                      const std::int64_t* stamps_ns, const std::int64_t* seg_first_block,
                      const std::int64_t* seg_ref_ns, std::size_t n_segments, bool with_time_s,
                      int num_threads = 0,
                      std::uint8_t return_type_before = kReturnTypeUnknown) const;

    const Vlp16Calibration& calibration() const { return calibration_; }
    const Vlp16DecoderConfig& config() const { return config_; }

private:
    struct PacketOut {
        Vlp16Point* points;
        float* time_s;       // null when not asked
        std::uint16_t* block_counts;  // 12 entries
    };
    /// Decode one packet into `out`; returns its status and the number of points.
    PacketStatus decode_packet(const std::uint8_t* raw, std::int64_t stamp_ns,
                               float rel_packet_stamp_s, std::uint8_t single_type,
                               std::int64_t flat_block0,
                               const std::int64_t* seg_first_block, const std::int64_t* seg_ref_ns,
                               std::size_t n_segments, PacketOut out, int& n_points,
                               bool& clipped) const;
    bool azimuth_in_range(std::uint16_t azimuth) const;
    /// x, y, z [m] and intensity of one return; false when the range filter drops it.
    bool point_of(int laser, std::uint16_t azimuth, const std::uint8_t* m, float& x, float& y,
                  float& z, float& intensity) const;

    Vlp16Calibration calibration_;
    Vlp16DecoderConfig config_;
    bool advanced_ = false;
    int min_azimuth_ = 0, max_azimuth_ = 36000;  // [0.01 deg]
    std::vector<float> cos_rot_table_, sin_rot_table_;  // 36000 entries, one per 0.01 deg
    std::array<float, 16> cos_rot_corr_{}, sin_rot_corr_{}, cos_vert_{}, sin_vert_{};
    // firing offsets [s] as velodyne-decoder's float table timing_offsets_[block][channel],
    // and the same exactly in [ns]
    std::array<std::array<float, 32>, 12> timing_s_{};
    std::array<std::array<std::int32_t, 32>, 12> timing_ns_{};
};

}  // namespace tripod
