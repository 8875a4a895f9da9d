// SPDX-License-Identifier: BSD-3-Clause
// The binary range coder: exact round trip at every probability, size near the entropy, and a
// cut stream is detected.
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

#include "tripod_core/range_coder.hpp"

namespace tripod {
namespace {

struct Coded {
    std::vector<uint32_t> p0;
    std::vector<int> bits;
    double entropy_bits = 0;
};

Coded random_bits(int n, unsigned seed) {
    std::mt19937 rng(seed);
    std::uniform_int_distribution<uint32_t> up(1, 65535);
    std::uniform_int_distribution<uint32_t> u16(0, 65535);
    Coded c;
    for (int i = 0; i < n; ++i) {
        const uint32_t p0 = (i % 3 == 0) ? up(rng) : (i % 3 == 1 ? 1u + (up(rng) % 64) : 65535u - (up(rng) % 64));
        const int bit = u16(rng) < p0 ? 0 : 1;  // drawn from the coded distribution
        c.p0.push_back(p0);
        c.bits.push_back(bit);
        c.entropy_bits -= std::log2((bit ? 65536.0 - p0 : static_cast<double>(p0)) / 65536.0);
    }
    return c;
}

TEST(RangeCoder, RoundTripsExactlyNearEntropy) {
    for (unsigned seed : {1u, 2u, 3u}) {
        const Coded c = random_bits(200000, seed);
        std::vector<uint8_t> bytes;
        RangeEncoder enc(bytes);
        for (size_t i = 0; i < c.bits.size(); ++i) enc.encode(c.p0[i], c.bits[i]);
        enc.finish();
        EXPECT_LT(bytes.size() * 8.0, c.entropy_bits * 1.01 + 64);

        RangeDecoder dec(bytes.data(), bytes.size());
        for (size_t i = 0; i < c.bits.size(); ++i) ASSERT_EQ(dec.decode(c.p0[i]), c.bits[i]) << i;
        EXPECT_FALSE(dec.overrun());
    }
}

TEST(RangeCoder, CutStreamIsDetected) {
    const Coded c = random_bits(50000, 9);
    std::vector<uint8_t> bytes;
    RangeEncoder enc(bytes);
    for (size_t i = 0; i < c.bits.size(); ++i) enc.encode(c.p0[i], c.bits[i]);
    enc.finish();
    RangeDecoder dec(bytes.data(), bytes.size() / 2);
    for (size_t i = 0; i < c.bits.size(); ++i) dec.decode(c.p0[i]);
    EXPECT_TRUE(dec.overrun());
}

}  // namespace
}  // namespace tripod
