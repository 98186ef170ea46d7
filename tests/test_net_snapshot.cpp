// A streaming client's snapshot: what it displays, rendered off screen from
// its own palettes (progskin-client --snapshot-every).
#include <gtest/gtest.h>

#ifndef PROGSKIN_HAVE_RENDER
TEST(NetSnapshot, NotBuilt) { GTEST_SKIP() << "render/ not built"; }
#else
#include <algorithm>
#include <filesystem>

#include "net_test_support.h"
#include "snapshot.h"

using namespace progskin;
using namespace progskin::net;
using namespace progskin::net::testing;

TEST(NetSnapshot, ClientRendersWhatItDisplays) {
    // The client renders in its display loop: under load (ctest -j on 2
    // cores) a software render can take a second, so the run leaves room
    // for two of them, and snapshots after the second are only checked.
    RunningServer s;
    ClientOptions o = s.client(4.0);
    o.max_kbps = 48;
    o.snapshot_every = 0.5;
    constexpr int kRendered = 2;
    int calls = 0, written = 0;
    size_t chars = 0;
    std::string err;
    const auto dir = std::filesystem::temp_directory_path() / "progskin_snapshot_test";
    std::filesystem::create_directories(dir);
    o.on_snapshot = [&](const DisplaySnapshot& snap) {
        ++calls;
        std::vector<render::SnapshotCharacter> cs;
        for (const DisplayedCharacter& d : snap.characters) {
            EXPECT_EQ(int(d.palette.size()), d.skin->bone_count());
            EXPECT_GE(d.bones, 1);
            EXPECT_LE(d.bones, d.skin->bone_count());
            render::SnapshotCharacter c;
            c.character = d.character;
            c.skin = d.skin;
            c.stream = d.stream;
            c.palette = d.palette;
            c.bones_received = d.bones;
            cs.push_back(c);
        }
        chars = std::max(chars, cs.size());
        if (calls > kRendered) return;
        const auto png = dir / ("snap_" + std::to_string(calls) + ".png");
        if (render::render_snapshot(cs, png.string(), {}, &err) && std::filesystem::file_size(png) > 1000) ++written;
    };
    run_client(o);
    std::filesystem::remove_all(dir);
    if (written == 0 && err.find("context") != std::string::npos) GTEST_SKIP() << err;
    EXPECT_GE(calls, 2);
    EXPECT_EQ(written, std::min(calls, kRendered)) << err;
    EXPECT_EQ(chars, default_instances(default_assets()).size());
}
#endif
