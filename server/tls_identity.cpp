// tls_identity.cpp — see tls_identity.h. OpenSSL 3 EVP/X509 APIs only.
#include "tls_identity.h"

#include <openssl/evp.h>
#include <openssl/pem.h>
#include <openssl/x509.h>
#include <openssl/x509v3.h>
#include <sys/stat.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <memory>

#include "crypto.h"
#include "errors.h"

namespace progskin::net {

namespace fs = std::filesystem;

namespace {

struct FileCloser {
    void operator()(FILE* f) const { std::fclose(f); }
};
using File = std::unique_ptr<FILE, FileCloser>;
using Key = std::unique_ptr<EVP_PKEY, decltype(&EVP_PKEY_free)>;
using Cert = std::unique_ptr<X509, decltype(&X509_free)>;

Cert read_cert(const std::string& path) {
    File f(std::fopen(path.c_str(), "rb"));
    if (!f) throw Error("cannot read TLS certificate " + path);
    Cert c(PEM_read_X509(f.get(), nullptr, nullptr, nullptr), X509_free);
    if (!c) throw Error("TLS certificate " + path + " is not a PEM certificate");
    return c;
}

std::string fingerprint(X509* c) {
    unsigned char md[EVP_MAX_MD_SIZE];
    unsigned int len = 0;
    if (!X509_digest(c, EVP_sha256(), md, &len)) throw Error("cannot compute a certificate fingerprint");
    return crypto::to_hex({md, len});
}

void add_ext(X509* cert, int nid, const char* value) {
    X509V3_CTX ctx;
    X509V3_set_ctx_nodb(&ctx);
    X509V3_set_ctx(&ctx, cert, cert, nullptr, nullptr, 0);
    X509_EXTENSION* ext = X509V3_EXT_conf_nid(nullptr, &ctx, nid, value);
    if (!ext) throw Error("cannot build a certificate extension");
    X509_add_ext(cert, ext, -1);
    X509_EXTENSION_free(ext);
}

}  // namespace

std::string default_tls_dir() {
    if (const char* x = std::getenv("XDG_CONFIG_HOME"); x && *x) return std::string(x) + "/progskin";
    if (const char* h = std::getenv("HOME"); h && *h) return std::string(h) + "/.config/progskin";
    return {};
}

std::string certificate_sha256(const std::string& cert_path) { return fingerprint(read_cert(cert_path).get()); }

TlsIdentity ensure_self_signed(const std::string& dir) {
    if (dir.empty()) throw Error("no directory for the TLS certificate (set XDG_CONFIG_HOME or HOME, or pass --tls-dir)");
    TlsIdentity id;
    id.cert_path = (fs::path(dir) / "server-cert.pem").string();
    id.key_path = (fs::path(dir) / "server-key.pem").string();
    const bool has_cert = fs::exists(id.cert_path), has_key = fs::exists(id.key_path);
    if (has_cert != has_key)
        throw Error("found " + (has_cert ? id.cert_path : id.key_path) + " without " + (has_cert ? id.key_path : id.cert_path) +
                    ": remove it to generate a new pair");
    if (has_cert) {
        Cert c = read_cert(id.cert_path);
        File f(std::fopen(id.key_path.c_str(), "rb"));
        if (!f) throw Error("cannot read TLS private key " + id.key_path);
        Key k(PEM_read_PrivateKey(f.get(), nullptr, nullptr, nullptr), EVP_PKEY_free);
        if (!k) throw Error("TLS private key " + id.key_path + " is not a PEM private key");
        if (X509_check_private_key(c.get(), k.get()) != 1)
            throw Error("TLS private key " + id.key_path + " does not match " + id.cert_path);
        id.sha256_hex = fingerprint(c.get());
        return id;
    }
    std::error_code ec;
    fs::create_directories(dir, ec);
    if (ec) throw Error("cannot create " + dir + ": " + ec.message());
    fs::permissions(dir, fs::perms::owner_all, fs::perm_options::replace, ec);

    Key key(EVP_EC_gen("P-256"), EVP_PKEY_free);
    if (!key) throw Error("cannot generate an EC P-256 key");
    Cert cert(X509_new(), X509_free);
    if (!cert) throw Error("cannot allocate a certificate");
    X509_set_version(cert.get(), 2);  // v3
    unsigned char serial[16];
    crypto::random_bytes(serial);
    serial[0] &= 0x7f;  // positive
    BIGNUM* bn = BN_bin2bn(serial, sizeof serial, nullptr);
    BN_to_ASN1_INTEGER(bn, X509_get_serialNumber(cert.get()));
    BN_free(bn);
    X509_gmtime_adj(X509_getm_notBefore(cert.get()), -60);
    X509_gmtime_adj(X509_getm_notAfter(cert.get()), 10L * 365 * 24 * 3600);
    X509_set_pubkey(cert.get(), key.get());
    X509_NAME* name = X509_get_subject_name(cert.get());
    X509_NAME_add_entry_by_txt(name, "CN", MBSTRING_ASC, reinterpret_cast<const unsigned char*>("progskin-server"), -1, -1, 0);
    X509_set_issuer_name(cert.get(), name);
    add_ext(cert.get(), NID_subject_alt_name, "IP:127.0.0.1,DNS:localhost");
    add_ext(cert.get(), NID_basic_constraints, "critical,CA:FALSE");
    add_ext(cert.get(), NID_key_usage, "critical,digitalSignature");
    add_ext(cert.get(), NID_ext_key_usage, "serverAuth");
    if (!X509_sign(cert.get(), key.get(), EVP_sha256())) throw Error("cannot sign the certificate");

    // Key first (0600 from creation), then the certificate: a crash in
    // between leaves a key without a certificate, reported on the next start.
    {
        const std::string tmp = id.key_path + ".tmp";
        const int old = ::umask(077);
        File f(std::fopen(tmp.c_str(), "wb"));
        ::umask(old);
        if (!f || !PEM_write_PrivateKey(f.get(), key.get(), nullptr, nullptr, 0, nullptr, nullptr))
            throw Error("cannot write TLS private key " + tmp);
        f.reset();
        fs::rename(tmp, id.key_path, ec);
        if (ec) throw Error("cannot write " + id.key_path + ": " + ec.message());
    }
    {
        const std::string tmp = id.cert_path + ".tmp";
        File f(std::fopen(tmp.c_str(), "wb"));
        if (!f || !PEM_write_X509(f.get(), cert.get())) throw Error("cannot write TLS certificate " + tmp);
        f.reset();
        fs::rename(tmp, id.cert_path, ec);
        if (ec) throw Error("cannot write " + id.cert_path + ": " + ec.message());
    }
    id.sha256_hex = fingerprint(cert.get());
    id.created = true;
    return id;
}

}  // namespace progskin::net
