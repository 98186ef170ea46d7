#include "plot.h"

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <random>
#include <sys/wait.h>

namespace progskin {
namespace {

std::string quoted(const std::string& s) {  // gnuplot single-quoted string
    std::string r = "'";
    for (char c : s) r += c == '\'' ? std::string("''") : std::string(1, c);
    return r + "'";
}

std::string shell_quoted(const std::string& s) {
    std::string r = "'";
    for (char c : s) r += c == '\'' ? std::string("'\\''") : std::string(1, c);
    return r + "'";
}

std::string lower_ext(const std::string& path) {
    std::string e = std::filesystem::path(path).extension().string();
    for (char& c : e) c = char(std::tolower(static_cast<unsigned char>(c)));
    return e;
}

}  // namespace

std::string gnuplot_terminal(const std::string& out_path, int width, int height) {
    const std::string e = lower_ext(out_path);
    char b[160];
    if (e == ".png")
        std::snprintf(b, sizeof b, "set terminal pngcairo size %d,%d font 'sans,11'", width, height);
    else if (e == ".pdf")
        std::snprintf(b, sizeof b, "set terminal pdfcairo size %.2fin,%.2fin font 'sans,10'", width / 96.0,
                      height / 96.0);
    else
        std::snprintf(b, sizeof b, "set terminal svg size %d,%d dynamic font 'sans,12' background '#ffffff'", width,
                      height);
    return b;
}

bool plot_error_tables(const std::vector<std::pair<std::string, std::vector<LodError>>>& tables,
                       const std::string& out_path, const std::string& title, std::string* error) {
    auto fail = [&](const std::string& m) {
        if (error) *error = m;
        return false;
    };
    if (tables.empty()) return fail("plot: no error tables");
    std::error_code ec;
    std::mt19937_64 rng(std::random_device{}());
    const auto dir = std::filesystem::temp_directory_path(ec) / ("progskin-plot-" + std::to_string(rng() % 1000000000));
    if (ec || !std::filesystem::create_directories(dir, ec)) return fail("plot: cannot create a temporary directory");
    const std::string dat = (dir / "error.dat").string(), gp = (dir / "error.gp").string();
    {
        std::ofstream d(dat);
        d << "# progskin inspect: error against bones; blocks per strategy (gnuplot index)\n"
          << "# bones  rms_pct  max_pct  rms  max\n";
        for (const auto& [name, t] : tables) {
            d << "# strategy " << name << "\n";
            for (const LodError& e : t)
                d << e.bones << " " << e.rms_pct << " " << e.max_pct << " " << e.rms << " " << e.max << "\n";
            d << "\n\n";
        }
        if (!d) return fail("plot: cannot write " + dat);
    }
    {
        std::ofstream s(gp);
        // Two panels side by side: RMS and max error (max is several times RMS).
        s << gnuplot_terminal(out_path, 1000, 440) << "\n"
          << "set output " << quoted(out_path) << "\n"
          << "set multiplot layout 1,2 title " << quoted(title) << " noenhanced\n"
          << "set xlabel 'bones k (active, progressive order)'\n"
          << "set grid lc rgb '#dddddd'\n"
          << "set key top right noenhanced\n"
          << "set xrange [0.5:*]\nset yrange [0:*]\n"
          << "set style data linespoints\n";
        for (int panel = 0; panel < 2; ++panel) {
            s << "set ylabel " << quoted(panel == 0 ? "RMS error, % of rest bounding-box diagonal"
                                                   : "max error, % of rest bounding-box diagonal")
              << "\n";
            if (panel == 1) s << "unset key\n";
            s << "plot \\\n";
            for (size_t i = 0; i < tables.size(); ++i)
                s << "  " << quoted(dat) << " index " << i << " using 1:" << (panel == 0 ? 2 : 3)
                  << " lw 2 pt 7 ps 0.45 lc " << i + 1 << " title " << quoted(tables[i].first)
                  << (i + 1 < tables.size() ? ", \\\n" : "\n");
        }
        s << "unset multiplot\n";
        if (!s) return fail("plot: cannot write " + gp);
    }
    const std::string log = (dir / "gnuplot.log").string();
    const std::string cmd = "gnuplot " + shell_quoted(gp) + " >" + shell_quoted(log) + " 2>&1";
    const int rc = std::system(cmd.c_str());
    if (rc != 0) {
        std::string msg;
        std::ifstream l(log);
        std::getline(l, msg, '\0');
        if (WIFEXITED(rc) && WEXITSTATUS(rc) == 127)
            return fail("plot: gnuplot not found (Debian: apt-get install gnuplot-nox); data and script kept in " +
                        dir.string());
        return fail("plot: gnuplot failed (" + msg + "); data and script kept in " + dir.string());
    }
    std::filesystem::remove_all(dir, ec);
    return true;
}

}  // namespace progskin
