// ctypes shim over the predictive-sph1 encoder of commit c8984a8 (fixture generation only)
#include <cstring>
#include "tripod_core/predictive_codec.hpp"
extern "C" long sph1_encode(const float* pts, long n, const double* origin, double range_step,
                            long az_count, double el_step, const double* el_table, long n_el,
                            int row_shift, unsigned char* out, long cap, double* max_err,
                            unsigned* checksum, double* part_bits) {
    tripod::PointsXYZ p(n, 3);
    std::memcpy(p.data(), pts, sizeof(float) * 3 * n);
    tripod::SphericalGrid g;
    for (int i = 0; i < 3; ++i) g.origin[i] = origin[i];
    g.range_step = range_step; g.az_count = az_count; g.el_step = el_step;
    g.el_table.assign(el_table, el_table + n_el); g.row_shift = row_shift;
    tripod::PredictiveStats s;
    auto v = tripod::predictive_encode(p, g, &s, 1);
    if ((long)v.size() > cap) return -1;
    std::memcpy(out, v.data(), v.size());
    *max_err = s.max_error_m; *checksum = s.checksum;
    for (int i = 0; i < 3; ++i) part_bits[i] = s.part_bits[i];
    return (long)v.size();
}
extern "C" int sph1_decode(const unsigned char* data, long size, long n, const double* origin,
                           double range_step, long az_count, double el_step,
                           const double* el_table, long n_el, int row_shift, unsigned checksum,
                           float* out) {
    tripod::SphericalGrid g;
    for (int i = 0; i < 3; ++i) g.origin[i] = origin[i];
    g.range_step = range_step; g.az_count = az_count; g.el_step = el_step;
    g.el_table.assign(el_table, el_table + n_el); g.row_shift = row_shift;
    try {
        auto p = tripod::predictive_decode(data, size, n, g, checksum, 1);
        std::memcpy(out, p.data(), sizeof(float) * 3 * n);
    } catch (...) { return -1; }
    return 0;
}
