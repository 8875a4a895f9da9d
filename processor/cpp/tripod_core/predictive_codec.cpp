// SPDX-License-Identifier: BSD-3-Clause
#include "tripod_core/predictive_codec.hpp"

#include <omp.h>

#include <algorithm>
#include <array>
#include <climits>
#include <cmath>
#include <stdexcept>
#include <string>

#include "tripod_core/range_coder.hpp"

namespace tripod {

namespace {

constexpr double kTwoPi = 6.283185307179586476925286766559;

int threads_for(int num_threads) { return num_threads > 0 ? num_threads : omp_get_max_threads(); }

// ---- adaptive binary models -----------------------------------------------------------------
// P(bit = 0) * 65536, adapted towards each coded bit at rate 1/2^shift; the shift grows with the
// number of bits seen (fast start, then a stable estimate), as in count-based models. Integer
// only, so the decoder repeats every update exactly.
struct AdaptiveBit {
    uint16_t p0 = 32768;
    uint8_t n = 0;
};

constexpr uint8_t kShiftOfCount[24] = {1, 2, 2, 3, 3, 3, 4, 4, 4, 4, 4, 4,
                                       5, 5, 5, 5, 5, 5, 5, 5, 5, 5, 5, 5};
constexpr int kMaxShift = 6;

inline void update(AdaptiveBit& m, int bit) {
    const int shift = m.n < 24 ? kShiftOfCount[m.n] : kMaxShift;
    if (m.n < 255) ++m.n;
    int p = m.p0;
    if (bit)
        p -= p >> shift;
    else
        p += (65536 - p) >> shift;
    m.p0 = static_cast<uint16_t>(std::clamp(p, 32, 65536 - 32));
}

// One template drives both directions, so encoder and decoder take the same path by
// construction: bit(model, b) codes b (encoder) or returns the decoded bit (decoder; b ignored).
// Cost of a bit of probability p / 4096 [bits], for the encoder's per-part accounting.
struct CostTable {
    float bits[4097];
    CostTable() {
        for (int i = 0; i <= 4096; ++i) bits[i] = -std::log2(std::max(i, 1) / 4096.0f);
    }
};
const CostTable kCost;

struct EncoderIo {
    RangeEncoder rc;
    double* cost = nullptr;  // where the bits of the current part are counted
    explicit EncoderIo(std::vector<uint8_t>& out) : rc(out) {}
    inline int bit(AdaptiveBit& m, int b) {
        rc.encode(m.p0, b);
        *cost += kCost.bits[(b ? 65536 - m.p0 : m.p0) >> 4];
        update(m, b);
        return b;
    }
    inline void part(double* c) { cost = c; }
};

struct DecoderIo {
    RangeDecoder rc;
    DecoderIo(const uint8_t* data, size_t size) : rc(data, size) {}
    inline int bit(AdaptiveBit& m, int /*b*/) {
        const int b = rc.decode(m.p0);
        update(m, b);
        return b;
    }
    inline void part(double*) {}
};

// ---- signed integers: zero flag, sign, Exp-Golomb magnitude with adaptive bins ---------------
constexpr int kMaxPrefix = 40;

struct IntModel {
    AdaptiveBit zero, sign;
    std::array<AdaptiveBit, kMaxPrefix> prefix;
    // mantissa bits below the leading one: the first two by position, the rest share one model
    std::array<std::array<AdaptiveBit, 3>, kMaxPrefix + 1> mantissa;
};

[[noreturn]] void corrupt(const char* what) {
    throw std::runtime_error(std::string("corrupt predictive stream: ") + what);
}

template <class Io>
inline int64_t code_int(Io& io, IntModel& m, int64_t v) {
    if (io.bit(m.zero, v == 0)) return 0;
    const int negative = io.bit(m.sign, v < 0);
    const uint64_t mag = v < 0 ? static_cast<uint64_t>(-v) : static_cast<uint64_t>(v);  // >= 1
    const int nb_in = mag ? 63 - __builtin_clzll(mag) : 0;
    int nb = 0;
    while (io.bit(m.prefix[nb], nb < nb_in)) {
        if (++nb == kMaxPrefix) corrupt("magnitude prefix too long");
    }
    uint64_t val = 1;
    for (int b = nb - 1; b >= 0; --b) {
        const int pos = std::min(nb - 1 - b, 2);
        val = (val << 1) | static_cast<uint64_t>(io.bit(m.mantissa[nb][pos], (mag >> b) & 1));
    }
    return negative ? -static_cast<int64_t>(val) : static_cast<int64_t>(val);
}

inline int bit_length(uint64_t v) { return v ? 64 - __builtin_clzll(v) : 0; }

// ---- the point model: contexts and predictors, shared by encoder and decoder ------------------
constexpr int kElContexts = 4;    // bit length of the previous elevation residual, at most 3
constexpr int64_t kUnknown = INT64_MIN;
constexpr int kAzBuckets = 16;    // bit length of the previous azimuth step
constexpr int kRangeBuckets = 8;     // bit length of the previous range residual
constexpr int kActivityBuckets = 8;  // bit length of the local range gradient |a-c| + |b-c|
constexpr size_t kHashedSlots = size_t{1} << 16;  // rows without an elevation table

struct QuantisedPoint {
    int64_t k;  // range index
    int64_t a;  // azimuth index in [0, az_count)
    int64_t e;  // elevation index
};

class PointModel {
public:
    PointModel(const SphericalGrid& grid)
        : az_count_(grid.az_count),
          table_(!grid.el_table.empty()),
          // with a table: its size; else the largest |index| of an elevation in [-pi/2, pi/2]
          n_el_(table_ ? static_cast<int64_t>(grid.el_table.size())
                       : std::llround(kTwoPi / 4 / grid.el_step) + 1),
          row_shift_(grid.row_shift),
          az_predictor_(grid.az_predictor),
          last_(table_ ? grid.el_table.size() : kHashedSlots, -1),
          before_(last_.size(), -1),
          az_last_(last_.size(), -1),
          az_before_(last_.size(), -1),
          successor_(last_.size(), kUnknown),
          el_(kElContexts),
          az_(2 * kAzBuckets),
          range_(2 * kActivityBuckets * kRangeBuckets) {}

    /// Code one point (encoder: `q` is the point; decoder: `q` is ignored, the point returned).
    double cost_bits[3] = {0, 0, 0};  // encoder: elevation, azimuth, range

    template <class Io>
    QuantisedPoint code(Io& io, const QuantisedPoint& q) {
        QuantisedPoint out;
        io.part(&cost_bits[0]);
        // elevation: residual against the successor of the previous point's row the last time
        // that row was seen (a scan repeats its row order, lasers' firing order included), or
        // against the previous step repeated
        const size_t prev_row = row_of(prev_.e);
        const int64_t el_pred =
            successor_[prev_row] != kUnknown ? successor_[prev_row] : prev_.e + prev_el_step_;
        const int64_t el_residual = code_int(
            io, el_[std::min(bit_length(std::abs(prev_el_residual_)), kElContexts - 1)],
            q.e - el_pred);
        out.e = el_pred + el_residual;
        if (table_ ? (out.e < 0 || out.e >= n_el_) : (out.e < -n_el_ || out.e > n_el_))
            corrupt("elevation index out of range");
        const int64_t el_step = out.e - prev_.e;
        successor_[prev_row] = out.e;
        // azimuth: residual against the previous azimuth (predictor A) or, with az_predictor 1,
        // against a + (b - c) over the azimuth image (predictor B; a: the previous azimuth, b:
        // this row's last one, c: the previous point's row's one before it: the step from one
        // firing to the next), whichever has the lower decaying residual score so far; scores
        // kept apart for points that stay in their row (dual returns, row-major scans) and
        // points that change row
        io.part(&cost_bits[1]);
        const size_t row = row_of(out.e);
        const int same = row == prev_row;
        const bool have_b = az_predictor_ == 1 && az_last_[row] >= 0 && az_before_[prev_row] >= 0;
        const int64_t pred_b =
            have_b ? wrap_index(prev_.a + wrap_step(az_last_[row] - az_before_[prev_row])) : 0;
        const bool use_b = have_b && az_score_b_[same] < az_score_a_[same];
        const int64_t az_pred = use_b ? pred_b : prev_.a;
        const int az_ctx = (el_residual == 0 ? 0 : kAzBuckets) +
                           std::min(bit_length(std::abs(prev_az_step_)), kAzBuckets - 1);
        const int64_t az_residual = code_int(io, az_[az_ctx], wrap_step(q.a - az_pred));
        if (az_residual > az_count_ || az_residual < -az_count_)
            corrupt("azimuth step out of range");
        out.a = wrap_index(az_pred + az_residual);
        if (az_predictor_ == 1) {  // both sides score both predictors on the decoded azimuth
            const auto score = [](int64_t& s, int64_t r) {
                s = s - (s >> 4) + std::min<int64_t>(std::abs(r), int64_t{1} << 32);
            };
            score(az_score_a_[same], wrap_step(out.a - prev_.a));
            if (have_b) score(az_score_b_[same], wrap_step(out.a - pred_b));
            az_before_[row] = az_last_[row];
            az_last_[row] = out.a;
        }
        const int64_t az_step = az_residual;  // the context of the next point
        // range: median edge detector (LOCO-I) over the scan seen as an image whose rows are the
        // elevation indices: a = the previous point, b = the last range of this row (the
        // previous sweep or revolution), c = the range that row e_{i-1} had before the previous
        // point overwrote it (b's neighbour in the previous sweep).
        io.part(&cost_bits[2]);
        const int64_t a = prev_.k;
        const int64_t b = last_[row] >= 0 ? last_[row] : a;
        const int64_t c = before_[prev_row] >= 0 ? before_[prev_row] : a;
        const int64_t lo = std::min(a, b), hi = std::max(a, b);
        const int64_t pred = c >= hi ? lo : (c <= lo ? hi : a + b - c);
        const int activity = std::min(bit_length(static_cast<uint64_t>(std::abs(a - c) +
                                                                       std::abs(b - c))),
                                      kActivityBuckets - 1);
        // the previous point repeated its value of the previous sweep: a static scene (or a
        // re-scanned column) is likely to repeat here too
        const int repeat = a == c && before_[prev_row] >= 0;
        const int ctx = (repeat * kActivityBuckets + activity) * kRangeBuckets +
                        std::min(bit_length(std::abs(prev_residual_)), kRangeBuckets - 1);
        const int64_t residual = code_int(io, range_[ctx], q.k - pred);
        out.k = pred + residual;
        if (out.k < 0) corrupt("negative range");
        before_[row] = last_[row];
        last_[row] = out.k;
        // state for the next point
        prev_ = out;
        prev_el_step_ = el_step;
        prev_el_residual_ = el_residual;
        prev_az_step_ = az_step;
        prev_residual_ = residual;
        return out;
    }

private:
    int64_t az_count_;
    bool table_;
    int64_t n_el_;
    inline size_t row_of(int64_t e) const {
        return table_ ? static_cast<size_t>(e)
                      : static_cast<size_t>(e >> row_shift_) & (kHashedSlots - 1);
    }

    inline int64_t wrap_step(int64_t d) const {  // into (-az_count/2, az_count/2]
        d %= az_count_;
        if (d > az_count_ / 2) d -= az_count_;
        if (d < -(az_count_ - 1) / 2) d += az_count_;
        return d;
    }
    inline int64_t wrap_index(int64_t a) const {  // into [0, az_count)
        a %= az_count_;
        return a < 0 ? a + az_count_ : a;
    }

    int row_shift_;
    int az_predictor_;
    std::vector<int64_t> last_, before_;  // last and previous range index per row (-1: none)
    std::vector<int64_t> az_last_, az_before_;  // the same for the azimuth index
    int64_t az_score_a_[2] = {0, 0}, az_score_b_[2] = {0, 0};  // by (row == previous row)
    std::vector<int64_t> successor_;      // elevation index that last followed each row
    std::vector<IntModel> el_, az_, range_;
    QuantisedPoint prev_{0, 0, 0};
    int64_t prev_el_step_ = 0, prev_el_residual_ = 0, prev_az_step_ = 0, prev_residual_ = 0;
};

// ---- quantisation and reconstruction ----------------------------------------------------------
struct Dequantiser {
    explicit Dequantiser(const SphericalGrid& g) : grid(g), az_step(kTwoPi / g.az_count) {
        for (double el : g.el_table) {
            cos_el.push_back(std::cos(el));
            sin_el.push_back(std::sin(el));
        }
    }
    /// Index of the laser whose beam cone (half-plane line through (0, z_j) at elevation el_j)
    /// lies nearest to the point at horizontal range h and height z about the origin.
    inline int64_t nearest_laser(double h, double z) const {
        int64_t best = 0;
        double best_d = INFINITY;
        const auto& zt = grid.z_table;
        for (size_t j = 0; j < zt.size(); ++j) {
            const double d = std::abs((z - zt[j]) * cos_el[j] - h * sin_el[j]);
            if (d < best_d) best_d = d, best = static_cast<int64_t>(j);
        }
        return best;
    }
    inline void point(const QuantisedPoint& q, float* xyz) const {
        const double r = static_cast<double>(q.k) * grid.range_step;
        double ce, se;
        if (!cos_el.empty()) {
            ce = cos_el[static_cast<size_t>(q.e)];
            se = sin_el[static_cast<size_t>(q.e)];
        } else {
            const double el = static_cast<double>(q.e) * grid.el_step;
            ce = std::cos(el);
            se = std::sin(el);
        }
        const double az = static_cast<double>(q.a) * az_step;
        xyz[0] = static_cast<float>(grid.origin[0] + r * ce * std::cos(az));
        xyz[1] = static_cast<float>(grid.origin[1] + r * ce * std::sin(az));
        const double z0 = grid.z_table.empty() ? 0.0 : grid.z_table[static_cast<size_t>(q.e)];
        xyz[2] = static_cast<float>(grid.origin[2] + z0 + r * se);
    }
    const SphericalGrid& grid;
    double az_step;
    std::vector<double> cos_el, sin_el;
};

/// FNV-1a over the quantised points: the decoder proves it rebuilt exactly what was coded.
uint32_t checksum(const std::vector<QuantisedPoint>& q) {
    uint32_t h = 2166136261u;
    for (const QuantisedPoint& p : q)
        for (int64_t v : {p.k, p.a, p.e}) {
            h = (h ^ static_cast<uint32_t>(v)) * 16777619u;
            h = (h ^ static_cast<uint32_t>(static_cast<uint64_t>(v) >> 32)) * 16777619u;
        }
    return h;
}

void check_grid(const SphericalGrid& g) {
    if (!(g.range_step > 0) || !std::isfinite(g.range_step))
        throw std::invalid_argument("range_step must be > 0");
    if (g.az_count < 2 || g.az_count > (int64_t{1} << 40))
        throw std::invalid_argument("az_count must be in [2, 2^40]");
    if (g.el_table.empty() && (!(g.el_step > 0) || !std::isfinite(g.el_step)))
        throw std::invalid_argument("el_step must be > 0 without an elevation table");
    if (g.row_shift < 0 || g.row_shift > 40) throw std::invalid_argument("row_shift in [0, 40]");
    if (!std::is_sorted(g.el_table.begin(), g.el_table.end()))
        throw std::invalid_argument("el_table must be sorted");
    if (!g.z_table.empty() && g.z_table.size() != g.el_table.size())
        throw std::invalid_argument("z_table must be empty or as long as el_table");
    for (double z : g.z_table)
        if (!std::isfinite(z)) throw std::invalid_argument("z_table must be finite");
    if (g.az_predictor != 0 && g.az_predictor != 1)
        throw std::invalid_argument("az_predictor must be 0 or 1");
}

}  // namespace

std::vector<double> cartesian_to_spherical(const PointsXYZ& points, const double origin[3],
                                           int num_threads) {
    const Eigen::Index n = points.rows();
    std::vector<double> out(static_cast<size_t>(n) * 3);
#pragma omp parallel for num_threads(threads_for(num_threads)) schedule(static)
    for (Eigen::Index i = 0; i < n; ++i) {
        const double x = points(i, 0) - origin[0], y = points(i, 1) - origin[1],
                     z = points(i, 2) - origin[2];
        const double h = std::hypot(x, y);
        out[3 * i] = std::sqrt(h * h + z * z);
        out[3 * i + 1] = std::atan2(y, x);
        out[3 * i + 2] = std::atan2(z, h);
    }
    return out;
}

std::vector<uint8_t> predictive_encode(const PointsXYZ& points, const SphericalGrid& grid,
                                       PredictiveStats* stats, int num_threads) {
    check_grid(grid);
    const Eigen::Index n = points.rows();
    const int nt = threads_for(num_threads);
    const std::vector<double> sph = cartesian_to_spherical(points, grid.origin, nt);
    std::vector<QuantisedPoint> q(static_cast<size_t>(n));
    const double az_step = kTwoPi / static_cast<double>(grid.az_count);
    const auto& table = grid.el_table;
    const Dequantiser lasers(grid);
    const bool per_laser = !grid.z_table.empty();
#pragma omp parallel for num_threads(nt) schedule(static)
    for (Eigen::Index i = 0; i < n; ++i) {
        QuantisedPoint& p = q[static_cast<size_t>(i)];
        if (per_laser) {  // laser, then the range from that laser's centre (0, 0, z_j)
            const double h = sph[3 * i] * std::cos(sph[3 * i + 2]);
            const double z = points(i, 2) - grid.origin[2];
            p.e = lasers.nearest_laser(h, z);
            p.k = std::llround(std::hypot(h, z - grid.z_table[static_cast<size_t>(p.e)]) /
                               grid.range_step);
            int64_t a = std::llround(sph[3 * i + 1] / az_step) % grid.az_count;
            p.a = a < 0 ? a + grid.az_count : a;
            continue;
        }
        p.k = std::llround(sph[3 * i] / grid.range_step);
        int64_t a = std::llround(sph[3 * i + 1] / az_step) % grid.az_count;
        p.a = a < 0 ? a + grid.az_count : a;
        const double el = sph[3 * i + 2];
        if (table.empty()) {
            p.e = std::llround(el / grid.el_step);
        } else {
            auto it = std::lower_bound(table.begin(), table.end(), el);
            size_t j = static_cast<size_t>(it - table.begin());
            if (j == table.size() || (j > 0 && el - table[j - 1] < table[j] - el)) --j;
            p.e = static_cast<int64_t>(j);
        }
    }
    if (stats) {  // the error the decoder's reconstruction will have, point by point
        const Dequantiser deq(grid);
        double worst = 0.0;
#pragma omp parallel for num_threads(nt) schedule(static) reduction(max : worst)
        for (Eigen::Index i = 0; i < n; ++i) {
            float xyz[3];
            deq.point(q[static_cast<size_t>(i)], xyz);
            const double dx = double(xyz[0]) - points(i, 0), dy = double(xyz[1]) - points(i, 1),
                         dz = double(xyz[2]) - points(i, 2);
            worst = std::max(worst, std::sqrt(dx * dx + dy * dy + dz * dz));
        }
        stats->max_error_m = worst;
        stats->checksum = checksum(q);
    }
    std::vector<uint8_t> out;
    out.reserve(static_cast<size_t>(n) + 64);
    EncoderIo io(out);
    PointModel model(grid);
    for (const QuantisedPoint& p : q) model.code(io, p);
    io.rc.finish();
    if (stats)
        for (int i = 0; i < 3; ++i) stats->part_bits[i] = model.cost_bits[i];
    return out;
}

PointsXYZ predictive_decode(const uint8_t* data, size_t size, uint64_t n_points,
                            const SphericalGrid& grid, uint32_t expected_checksum,
                            int num_threads) {
    check_grid(grid);
    if (n_points > (uint64_t{1} << 34)) corrupt("implausible point count");
    std::vector<QuantisedPoint> q(static_cast<size_t>(n_points));
    {
        DecoderIo io(data, size);
        PointModel model(grid);
        const QuantisedPoint none{0, 0, 0};
        for (uint64_t i = 0; i < n_points; ++i) {
            q[i] = model.code(io, none);
            if ((i & 0xFFFF) == 0 && io.rc.overrun()) corrupt("stream ends early");
        }
        if (io.rc.overrun()) corrupt("stream ends early");
    }
    if (checksum(q) != expected_checksum) corrupt("checksum of the decoded points mismatch");
    PointsXYZ out(static_cast<Eigen::Index>(n_points), 3);
    const Dequantiser deq(grid);
    const Eigen::Index n = out.rows();
#pragma omp parallel for num_threads(threads_for(num_threads)) schedule(static)
    for (Eigen::Index i = 0; i < n; ++i) deq.point(q[static_cast<size_t>(i)], out.data() + 3 * i);
    return out;
}

}  // namespace tripod
