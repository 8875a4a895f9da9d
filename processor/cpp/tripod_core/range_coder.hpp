// SPDX-License-Identifier: BSD-3-Clause
// Binary range coder with 16-bit probabilities (carry-propagating, LZMA style).
//
// Integer-only, so the decoder reproduces the encoder exactly on every platform. A probability
// is P(bit == 0) scaled to [1, 65535]; the coder splits the 32-bit range at
// bound = (range >> 16) * p0, so range >= 2^24 after normalisation keeps >= 8 bits of
// resolution in the split.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

namespace tripod {

/// Encoder: append bits with encode(p0, bit), then finish() once.
class RangeEncoder {
public:
    explicit RangeEncoder(std::vector<uint8_t>& out) : out_(out) {}

    /// Code one bit with probability p0 = P(bit == 0) * 65536, 1 <= p0 <= 65535.
    inline void encode(uint32_t p0, int bit) {
        const uint32_t bound = (range_ >> 16) * p0;
        if (bit) {
            low_ += bound;
            range_ -= bound;
        } else {
            range_ = bound;
        }
        while (range_ < (1u << 24)) {
            range_ <<= 8;
            shift_low();
        }
    }

    /// Flush the remaining state (5 bytes); the stream is complete afterwards.
    void finish() {
        for (int i = 0; i < 5; ++i) shift_low();
    }

private:
    inline void shift_low() {
        if (static_cast<uint32_t>(low_) < 0xFF000000u || (low_ >> 32) != 0) {
            const uint8_t carry = static_cast<uint8_t>(low_ >> 32);
            uint8_t temp = cache_;
            do {
                out_.push_back(static_cast<uint8_t>(temp + carry));
                temp = 0xFF;
            } while (--cache_size_ != 0);
            cache_ = static_cast<uint8_t>(low_ >> 24);
        }
        ++cache_size_;
        low_ = (low_ & 0x00FFFFFFu) << 8;
    }

    std::vector<uint8_t>& out_;
    uint64_t low_ = 0;
    uint32_t range_ = 0xFFFFFFFFu;
    uint8_t cache_ = 0;
    uint64_t cache_size_ = 1;
};

/// Decoder over a byte span; reading past the end yields zero bytes and sets overrun().
class RangeDecoder {
public:
    RangeDecoder(const uint8_t* data, size_t size) : data_(data), size_(size) {
        for (int i = 0; i < 5; ++i) code_ = (code_ << 8) | next_byte();
    }

    /// Decode one bit coded with the same p0 as the encoder used.
    inline int decode(uint32_t p0) {
        const uint32_t bound = (range_ >> 16) * p0;
        int bit;
        if (code_ < bound) {
            range_ = bound;
            bit = 0;
        } else {
            code_ -= bound;
            range_ -= bound;
            bit = 1;
        }
        while (range_ < (1u << 24)) {
            range_ <<= 8;
            code_ = (code_ << 8) | next_byte();
        }
        return bit;
    }

    /// True when the decoder needed more bytes than the stream holds (corrupt or cut input).
    bool overrun() const { return pos_ > size_; }

private:
    inline uint32_t next_byte() {
        const uint32_t b = pos_ < size_ ? data_[pos_] : 0u;
        ++pos_;
        return b;
    }

    const uint8_t* data_;
    size_t size_;
    size_t pos_ = 0;
    uint32_t code_ = 0;
    uint32_t range_ = 0xFFFFFFFFu;
};

}  // namespace tripod
