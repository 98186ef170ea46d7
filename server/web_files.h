// web_files.h — the read-only static file server behind progskin-server
// --web (docs/browser.md): the browser client's page (index.html, its
// JavaScript, the WebAssembly client, three.js) answered to HTTP GET on the
// same port as the WebSocket endpoint /ws (web_endpoint.h). No socket here:
// a request's method and target in, one whole HTTP/1.1 response out
// (Connection: close), so tests drive it directly.
//
// Bounds and refusals: only GET and HEAD (else 405); a target at most
// kMaxTarget bytes, made only of [A-Za-z0-9._/-] after the query is cut
// (no %-escapes, no backslash), with no empty, "." or ".." segment and no
// segment starting with '.' (else 400); "/" is "/index.html". The file must
// be a regular file inside the root after symbolic links are resolved, at
// most kMaxFileBytes (else 404 / 413). Content-Type by extension
// (application/wasm for .wasm, text/javascript for .js, ...;
// application/octet-stream otherwise), X-Content-Type-Options: nosniff,
// Cache-Control: no-cache.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

namespace progskin::net {

class WebFiles {
public:
    static constexpr size_t kMaxTarget = 256;
    static constexpr uint64_t kMaxFileBytes = uint64_t(8) << 20;  // the wasm is 0.9 MB, three.core.js 1.4 MB
    // root: the folder served; empty: none (every file request is 404, saying
    // how to build the page). Throws Error when root is given and is not a folder.
    explicit WebFiles(const std::string& root);
    const std::string& root() const { return root_; }
    // The whole response (status line, headers, body: none for HEAD) to
    // `method` `target` (the request line's two first words). status: the code.
    std::vector<uint8_t> respond(const std::string& method, const std::string& target, int& status) const;

    // The folder progskin-server serves: `flag` (--web-root) when not empty;
    // else <prefix>/share/progskin/web for an installed binary in <prefix>/bin;
    // else <binary's folder>/../web (the build tree: build/server/progskin-server
    // and build/web). Empty when none exists. exe: the binary's path.
    static std::string find_root(const std::string& flag, const std::string& exe);
    static const char* content_type(const std::string& path);

private:
    std::string root_;  // canonical
};

}  // namespace progskin::net
