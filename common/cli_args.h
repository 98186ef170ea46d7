// cli_args.h — the command-line parsing shared by the progskin commands:
// positional arguments, flags and valued options (--key VALUE or --key=VALUE),
// unknown options refused with a UsageError (exit code 2 in every command),
// and strict numbers (to_number, to_int, to_u16, to_port: the whole value must parse,
// the error names the option) and HOST:PORT values (host_port) for the
// streaming commands' own loops too.
#pragma once
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <map>
#include <stdexcept>
#include <string>
#include <vector>

namespace progskin::cli {

struct UsageError : std::runtime_error {
    using std::runtime_error::runtime_error;
};

struct Args {
    std::vector<std::string> positional;
    std::map<std::string, std::string> opts;
    bool has(const std::string& k) const { return opts.count(k) > 0; }
    std::string get(const std::string& k, const std::string& d = "") const {
        auto it = opts.find(k);
        return it == opts.end() ? d : it->second;
    }
};

inline Args parse(int argc, char** argv, int first, const std::vector<std::string>& flags,
           const std::vector<std::string>& valued) {
    Args a;
    for (int i = first; i < argc; ++i) {
        std::string s = argv[i];
        if (s.rfind("--", 0) == 0 || s == "-o") {
            std::string key = s, value;
            const auto eq = s.find('=');
            if (eq != std::string::npos) {
                key = s.substr(0, eq);
                value = s.substr(eq + 1);
            }
            const bool is_flag = std::find(flags.begin(), flags.end(), key) != flags.end();
            const bool is_valued = std::find(valued.begin(), valued.end(), key) != valued.end();
            if (!is_flag && !is_valued) throw UsageError("unknown option " + key);
            if (is_valued && eq == std::string::npos) {
                if (i + 1 >= argc) throw UsageError(key + " needs a value");
                value = argv[++i];
            }
            a.opts[key] = value;
        } else {
            a.positional.push_back(s);
        }
    }
    return a;
}

inline double to_number(const std::string& key, const std::string& v) {
    try {
        size_t n = 0;
        const double d = std::stod(v, &n);
        if (n != v.size() || !std::isfinite(d)) throw 0;
        return d;
    } catch (...) {
        throw UsageError(key + ": '" + v + "' is not a number");
    }
}

inline int to_int(const std::string& key, const std::string& v) {
    const double d = to_number(key, v);
    if (d != std::floor(d) || d < 0 || d > 1e9) throw UsageError(key + ": '" + v + "' is not a non-negative integer");
    return int(d);
}

// An integer 0..65535; `what` names it in the error ("a port").
inline uint16_t to_u16(const std::string& key, const std::string& v, const char* what = "a 16-bit integer") {
    const int p = to_int(key, v);
    if (p > 65535) throw UsageError(key + ": '" + v + "' is not " + what + " (0-65535)");
    return uint16_t(p);
}

inline uint16_t to_port(const std::string& key, const std::string& v) { return to_u16(key, v, "a port"); }

// A value that must be `a` or `b` (an option's two choices): v itself.
inline std::string one_of(const std::string& key, const std::string& v, const char* a, const char* b) {
    if (v != a && v != b) throw UsageError(key + " takes " + a + " or " + b + ", not " + v);
    return v;
}

// HOST:PORT, split at the last colon; both parts required.
struct HostPort {
    std::string host;
    uint16_t port = 0;
};
inline HostPort host_port(const std::string& key, const std::string& v) {
    const auto c = v.rfind(':');
    if (c == std::string::npos || c == 0) throw UsageError(key + " needs HOST:PORT, not '" + v + "'");
    return {v.substr(0, c), to_port(key, v.substr(c + 1))};
}

}  // namespace progskin::cli
