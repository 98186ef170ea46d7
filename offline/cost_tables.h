// cost_tables.h — computing, storing and reading an asset's cost model
// (common/cost_model.h). Offline: `progskin build` stores the tables in the
// PROGSKIN_progressive_skin extension under "server"; the server computes
// them once for a plain file and caches them, so that loading builds nothing.
#pragma once
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "animation.h"
#include "character.h"
#include "cost_model.h"
#include "progressive_skin.h"

namespace progskin {

// The lower convex hull of the points (k, e[k - 1]), k = 1..B, as steps. O(B).
std::vector<HullStep> error_hull(const std::vector<double>& e);

// The tables of character c with skin s over its clip selections (one model
// per selection and a last one over all of them), at 30 fps: diagonal, bind
// radius, translation box, scale range, motion, and per segment the collapse,
// gap, refresh and show-value tables (cost_model.h). Cost: the error table
// per selection (evaluate_error_table) plus one skinning of the mesh per
// sampled interval, up to 24 start frames per selection and gap (2..16).
// `selections` must not be empty. Throws Error on an invalid skin.
AssetTables compute_asset_tables(const Character& c, const ProgressiveSkin& s,
                                 const std::vector<ClipSelection>& selections);

// The tables as JSON (values to 7 significant digits), versioned
// (kServerTablesVersion) with the constants they were computed with.
nlohmann::json asset_tables_json(const AssetTables& t, int bones, size_t selections);
// Reads asset_tables_json output for an asset of `bones` bones and
// `selections` clip selections into out. Returns false, leaving `out` as it
// was and saying why in *why, when the JSON is absent, of another version or
// constants, or does not fit (bone count, selections, segment layout).
// Throws nothing.
bool read_asset_tables(const nlohmann::json& j, int bones, size_t selections, AssetTables& out,
                       std::string* why = nullptr);

}  // namespace progskin
