// delta_records_probe.cpp — how many bits a frame-stream bone record
// (proto/bone_codec.h, 96 bits) would need as a delta against the same bone's
// record d ticks earlier: the server's own FrameEncoder on the default
// character set (Fox's 3 clip groups and CesiumMan, 300 ticks at 30 Hz).
// Issue 3 left "records relative to an acknowledged frame" optional; this
// measures what it could save. "shared width": a flag bit, a 4-bit width and
// the six quantised fields' differences zigzag-coded at that width; a record
// whose largest quaternion component changed is sent plain (escape). "per-field
// ideal": each difference at its own zigzag width, with no cost for saying the
// width (a lower bound for coders of this kind).
//
// Build (from the repository root, after the README's test build in build/):
//   g++ -std=c++20 -O2 -Icommon -Iproto -Iserver -Ibuild/proto docs/experiments/delta_records_probe.cpp
//       build/server/libprogskin_net.a build/proto/libprogskin_proto.a build/common/libprogskin_core.a
//       -ltinygltf -lpthread -o /tmp/delta_probe && /tmp/delta_probe
#include <cmath>
#include <cstdio>
#include <vector>
#include "frame_encoder.h"
#include "scene.h"
using namespace progskin;
using namespace progskin::net;
static void fields(const uint8_t* r, int& big, long f[6]) {
    uint64_t bits = 0;
    for (int i = 0; i < 6; ++i) bits |= uint64_t(r[i]) << (8 * i);
    big = int(bits & 3);
    for (int i = 0; i < 3; ++i) f[i] = long((bits >> (2 + 15 * i)) & 0x7fff);
    for (int a = 0; a < 3; ++a) f[3 + a] = long(r[6 + 2 * a]) | (long(r[7 + 2 * a]) << 8);
}
static int width(long d) {  // bits of the zigzag code
    unsigned long z = d < 0 ? (unsigned long)(-2 * d - 1) : (unsigned long)(2 * d);
    int w = 0;
    while (z) ++w, z >>= 1;
    return w;
}
int main() {
    auto paths = default_asset_paths(".");
    std::vector<std::shared_ptr<ServerAsset>> assets;
    for (auto& p : paths) assets.push_back(load_server_asset(p));
    auto inst = default_instances(assets);
    FrameEncoder enc(assets, inst, 30.0f);
    const int T = 300;
    std::vector<EncodedFrame> frames;
    for (int t = 0; t < T; ++t) frames.push_back(enc.encode(uint32_t(t)));
    std::printf("%zu instances, %d ticks at 30 Hz\n", inst.size(), T);
    const double kPlainBits = 8.0 * RecordFormat::kPlainSize;
    for (int d : {1, 2, 3, 6, 10}) {
        double packed = 0, ideal = 0, n = 0, escapes = 0;
        for (int t = d; t < T; ++t)
            for (size_t i = 0; i < inst.size(); ++i) {
                const EncodedInstance& e = frames[size_t(t)].instances[i];
                if (e.record_size != RecordFormat::kPlainSize) continue;
                for (int b = 0; b < e.bone_count; ++b) {
                    int bc, br;
                    long fc[6], fr[6];
                    fields(frames[size_t(t)].records(int(i)) + RecordFormat::kPlainSize * b, bc, fc);
                    fields(frames[size_t(t - d)].records(int(i)) + RecordFormat::kPlainSize * b, br, fr);
                    n += 1;
                    if (bc != br) {
                        escapes += 1;
                        packed += 1 + kPlainBits;
                        ideal += kPlainBits;
                        continue;
                    }
                    int w = 0;
                    double id = 0;
                    for (int k = 0; k < 6; ++k) {
                        w = std::max(w, width(fc[k] - fr[k]));
                        id += width(fc[k] - fr[k]);
                    }
                    packed += 1 + 4 + 6 * w;  // flag, width, six fields of that width
                    ideal += id;              // each field at its own zigzag width (no length cost)
                }
            }
        std::printf("lag %2d ticks: records %.0f, escapes %.1f %%, shared-width delta %.1f %% of plain, per-field ideal %.1f %%\n",
                    d, n, 100 * escapes / n, 100 * packed / (n * kPlainBits), 100 * ideal / (n * kPlainBits));
    }
}
