// client_asset.h — what a game gets of a character the client displays
// (client.h RemoteCharacter): the asset of the server's catalogue it is an
// instance of, and the clip it plays. Public (installed with client.h);
// what the client builds from them to display it (InstanceView, the pose
// buffer) is in client_palette.h, internal.
#pragma once
#include <cstdint>
#include <string>

#include "animation.h"
#include "bone_codec.h"
#include "character.h"
#include "progressive_skin.h"

namespace progskin::net {

// An asset as the client holds it: the character imported from the
// downloaded file and the progressive skin described in Welcome.
struct ClientAsset {
    uint64_t id = 0;
    std::string name, path;
    Character character;
    ProgressiveSkin skin;   // order, parents, corrections, error; joints/weights in progressive indices
    RecordFormat format;
    double diagonal = 1;    // rest_diagonal(character)
    SkinStream stream;      // skin's vertex stream for skin_stream (positions, U16 weights)
};

// The clip an instance plays (control.fbs Instance), as announced by the
// server or by the character's publisher.
struct ClipInfo {
    ClipSelection selection;  // empty clips: live poses (no reference)
    float time_offset = 0, speed = 1;
    bool once = false;        // plays once and holds the last frame (else loops)
    // Clip time of the selection u seconds after its start (looped, or held).
    double at(double u) const;
    double clip_time(double tick, double tick_rate) const;
};

}  // namespace progskin::net
