// datagram_packer.cpp — see datagram_packer.h.
#include "datagram_packer.h"

#include <algorithm>
#include <cassert>

#include "error.h"
#include "wire.h"

namespace progskin::net {

void DatagramPacker::flush(uint32_t tick, uint32_t& seq, std::vector<std::vector<uint8_t>>& out, size_t& wire) {
    if (chunks_.empty()) return;
    fbb_.Clear();
    auto ch = fbb_.CreateVectorOfStructs(chunks_.data(), chunks_.size());
    auto rec = fbb_.CreateVector(records_.data(), records_.size());
    auto fr = wire::CreateFrame(fbb_, tick, ch, rec);
    auto dg = wire::CreateDatagram(fbb_, seq++, now_us32(), wire::DatagramBody::Frame, fr.Union());
    fbb_.Finish(dg, wire::DatagramIdentifier());
    const size_t size = fbb_.GetSize();
    // WireCost::kFrameOverhead must cover the tables; this is what the tests check.
    if (size > MAX_DATAGRAM || size > records_.size() + chunks_.size() * WireCost::kChunk + WireCost::kFrameOverhead)
        throw Error("datagram_packer: frame overhead " + std::to_string(size - records_.size() - chunks_.size() * 6) +
                    " bytes exceeds WireCost::kFrameOverhead");
    out.emplace_back(fbb_.GetBufferPointer(), fbb_.GetBufferPointer() + size);
    wire += size + UDP_IP_OVERHEAD;
    chunks_.clear();
    records_.clear();
}

size_t DatagramPacker::pack(const EncodedFrame& frame, std::span<const Pick> picks, uint32_t& seq,
                            std::vector<std::vector<uint8_t>>& out) {
    const size_t room = MAX_DATAGRAM - WireCost::kFrameOverhead;
    size_t wire = 0;
    chunks_.clear();
    records_.clear();
    for (const Pick& p : picks) {
        const EncodedInstance& e = frame.instances[p.instance];
        const int k = std::min(p.k, e.bone_count);
        const uint8_t* src = frame.records(p.instance);
        int first = std::clamp(p.first, 0, k);
        const int show = std::clamp(p.show, k, e.bone_count);
        while (first < k) {
            size_t used = records_.size() + (chunks_.size() + 1) * WireCost::kChunk;
            int fit = used >= room ? 0 : int((room - used) / size_t(e.record_size));
            if (fit <= 0) {
                flush(frame.tick, seq, out, wire);
                continue;
            }
            int count = std::min(fit, k - first);
            chunks_.emplace_back(uint16_t(p.instance), uint8_t(first), uint8_t(count), uint8_t(show), uint8_t(show));
            records_.insert(records_.end(), src + size_t(first) * e.record_size,
                            src + size_t(first + count) * e.record_size);
            first += count;
        }
    }
    flush(frame.tick, seq, out, wire);
    return wire;
}

}  // namespace progskin::net
