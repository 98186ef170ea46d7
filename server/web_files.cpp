// web_files.cpp — see web_files.h.
#include "web_files.h"

#include <cctype>
#include <filesystem>
#include <fstream>

#include "errors.h"

namespace progskin::net {

namespace fs = std::filesystem;

namespace {

std::vector<uint8_t> response(int status, const char* reason, const char* type, const std::string& body, bool head,
                              const std::vector<uint8_t>* file = nullptr) {
    const size_t len = file ? file->size() : body.size();
    std::string h = "HTTP/1.1 " + std::to_string(status) + " " + reason + "\r\nContent-Type: " + type +
                    "\r\nContent-Length: " + std::to_string(len) +
                    "\r\nX-Content-Type-Options: nosniff\r\nCache-Control: no-cache\r\nConnection: close\r\n\r\n";
    std::vector<uint8_t> out(h.begin(), h.end());
    if (!head) {
        if (file) out.insert(out.end(), file->begin(), file->end());
        else out.insert(out.end(), body.begin(), body.end());
    }
    return out;
}

bool safe_target(const std::string& t) {
    if (t.empty() || t.size() > WebFiles::kMaxTarget || t[0] != '/') return false;
    for (char ch : t)
        if (!(std::isalnum(static_cast<unsigned char>(ch)) || ch == '.' || ch == '_' || ch == '-' || ch == '/')) return false;
    size_t at = 1;
    while (at <= t.size()) {
        const size_t end = std::min(t.find('/', at), t.size());
        const std::string seg = t.substr(at, end - at);
        if (seg.empty() || seg[0] == '.') return false;  // "", ".", "..", hidden files
        at = end + 1;
    }
    return true;
}

}  // namespace

WebFiles::WebFiles(const std::string& root) {
    if (root.empty()) return;
    std::error_code ec;
    if (!fs::is_directory(root, ec)) throw Error("web root " + root + " is not a folder");
    root_ = fs::canonical(root, ec).string();
    if (ec) throw Error("web root " + root + ": " + ec.message());
}

const char* WebFiles::content_type(const std::string& path) {
    const std::string ext = fs::path(path).extension().string();
    if (ext == ".html") return "text/html; charset=utf-8";
    if (ext == ".js" || ext == ".mjs") return "text/javascript; charset=utf-8";
    if (ext == ".wasm") return "application/wasm";
    if (ext == ".css") return "text/css; charset=utf-8";
    if (ext == ".json") return "application/json";
    if (ext == ".png") return "image/png";
    if (ext == ".svg") return "image/svg+xml";
    if (ext == ".txt") return "text/plain; charset=utf-8";
    return "application/octet-stream";
}

std::vector<uint8_t> WebFiles::respond(const std::string& method, const std::string& target, int& status) const {
    const bool head = method == "HEAD";
    const char* text = "text/plain; charset=utf-8";
    if (method != "GET" && !head) {
        status = 405;
        return response(405, "Method Not Allowed", text, "only GET and HEAD\n", false);
    }
    std::string path = target.substr(0, target.find('?'));
    if (path == "/") path = "/index.html";
    if (!safe_target(path)) {
        status = 400;
        return response(400, "Bad Request", text, "refused path\n", head);
    }
    if (root_.empty()) {
        status = 404;
        return response(404, "Not Found", text,
                        "this server has no web root: build the page (scripts/build_web.sh) or pass --web-root DIR\n", head);
    }
    std::error_code ec;
    const fs::path file = fs::canonical(fs::path(root_) / path.substr(1), ec);
    const std::string fs_ = file.string();
    if (ec || fs_.compare(0, root_.size(), root_) != 0 || (fs_.size() > root_.size() && fs_[root_.size()] != '/') ||
        !fs::is_regular_file(file, ec)) {
        status = 404;
        return response(404, "Not Found", text, "not found\n", head);
    }
    const uint64_t size = fs::file_size(file, ec);
    if (ec || size > kMaxFileBytes) {
        status = 413;
        return response(413, "Content Too Large", text, "file too large\n", head);
    }
    std::vector<uint8_t> bytes(head ? 0 : size_t(size));
    if (!head) {
        std::ifstream f(file, std::ios::binary);
        if (!f.read(reinterpret_cast<char*>(bytes.data()), std::streamsize(size))) {
            status = 404;
            return response(404, "Not Found", text, "cannot read\n", head);
        }
    } else {
        bytes.resize(size_t(size));  // Content-Length only
    }
    status = 200;
    return response(200, "OK", content_type(fs_), {}, head, &bytes);
}

std::string WebFiles::find_root(const std::string& flag, const std::string& exe) {
    if (!flag.empty()) return flag;
    std::error_code ec;
    const fs::path bin = fs::canonical(exe, ec).parent_path();
    if (ec || bin.empty()) return {};
    for (const fs::path& p : {bin.parent_path() / "share" / "progskin" / "web", bin.parent_path() / "web"})
        if (fs::is_regular_file(p / "index.html", ec)) return p.string();
    return {};
}

}  // namespace progskin::net
