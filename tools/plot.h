// plot.h — plots drawn by gnuplot (Debian package gnuplot-nox).
//
// progskin writes a gnuplot data file and script into a temporary directory,
// runs `gnuplot` on them and removes them on success (kept, and named in the
// error, on failure). Output format from the extension: .svg (default), .png
// (pngcairo) or .pdf (pdfcairo).
#pragma once
#include <string>
#include <utility>
#include <vector>

#include "progressive_skin.h"

namespace progskin {

// Error against bones, one line per strategy, in two panels: RMS error (left)
// and max error (right), in % of the rest bounding-box diagonal, k = 1..B.
// Returns false and sets *error when gnuplot is missing or fails.
bool plot_error_tables(const std::vector<std::pair<std::string, std::vector<LodError>>>& tables,
                       const std::string& out_path, const std::string& title, std::string* error = nullptr);

// The gnuplot `set terminal` line for a path (by extension).
std::string gnuplot_terminal(const std::string& out_path, int width, int height);

}  // namespace progskin
