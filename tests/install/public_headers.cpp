// Every public header, included as a game does, beside standard and system
// headers whose names a flat include directory would shadow.
#include <error.h>
#include <math.h>

#include <cmath>
#include <cstdio>

#include <progskin/animation.h>
#include <progskin/bone_codec.h>
#include <progskin/bone_record.h>
#include <progskin/character.h>
#include <progskin/client.h>
#include <progskin/client_asset.h>
#include <progskin/cost_model.h>
#include <progskin/error_metric.h>
#include <progskin/errors.h>
#include <progskin/gltf_import.h>
#include <progskin/mat34.h>
#include <progskin/palette.h>
#include <progskin/pose.h>
#include <progskin/progressive_asset.h>
#include <progskin/progressive_skin.h>
#include <progskin/progskin.h>  // the C API, from C++
#include <progskin/scene.h>
#include <progskin/server.h>
#include <progskin/skinning.h>
#include <progskin/view.h>

int main() {
    // <error.h> is glibc's, <math.h> the C library's: both usable.
    error_message_count = 0;
    const double s = std::sqrt(4.0) + sqrt(9.0);
    // The library links: a pose round trip through its matrix.
    progskin::BonePose p;
    p.t = {1.0f, 2.0f, 3.0f};
    const progskin::BonePose q = progskin::decompose(progskin::compose(p));
    progskin::net::ClientConfig cfg;
    std::printf("public headers ok: %g %g %d\n", s, double(q.t.y), int(cfg.tls));
    return (s == 5.0 && std::fabs(q.t.y - 2.0f) < 1e-6f) ? 0 : 1;
}
