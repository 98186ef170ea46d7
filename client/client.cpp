// client.cpp — see client.h. Session: TCP connect -> Hello -> Welcome (or
// Refuse) -> AssetRequest/AssetChunk for uncached assets -> View -> UDP Bind
// until BindAck or a Frame -> frames + Acks (+ Stats each second) -> Goodbye.
#include "client.h"

#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <time.h>

#include <algorithm>
#include <asio.hpp>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <thread>
#include <unistd.h>
#include <map>
#include <memory>
#include <sstream>

#include "client_palette.h"
#include "error.h"
#include "error_metric.h"
#include "frame_reader.h"
#include "gltf_import.h"
#include "wire.h"

namespace progskin::net {

using asio::ip::tcp;
using asio::ip::udp;
namespace fs = std::filesystem;

namespace {

class ControlChannel {
public:
    explicit ControlChannel(asio::io_context& io) : sock(io) {}
    tcp::socket sock;

    void send(const flatbuffers::FlatBufferBuilder& fbb) {
        std::vector<uint8_t> msg;
        frame_control(fbb, msg);
        asio::error_code ec;
        sock.non_blocking(false, ec);
        asio::write(sock, asio::buffer(msg), ec);
        if (ec) throw Error("control channel: " + ec.message());
    }

    // Next complete message body, or false after `timeout` seconds (0: poll once).
    bool next(std::vector<uint8_t>& body, double timeout) {
        const double deadline = now_seconds() + timeout;
        for (;;) {
            uint32_t n = 0;
            if (read_length(rx_, n)) {
                if (n < 8 || n > MAX_CONTROL_MESSAGE) throw Error("server sent a control message of " + std::to_string(n) + " bytes");
                if (rx_.size() >= 4 + size_t(n)) {
                    body.assign(rx_.begin() + 4, rx_.begin() + 4 + n);
                    rx_.erase(rx_.begin(), rx_.begin() + 4 + n);
                    return true;
                }
            }
            double left = deadline - now_seconds();
            pollfd p{sock.native_handle(), POLLIN, 0};
            int r = ::poll(&p, 1, left > 0 ? int(left * 1000) + 1 : 0);
            if (r <= 0) return false;
            uint8_t buf[65536];
            asio::error_code ec;
            sock.non_blocking(true, ec);
            size_t got = sock.read_some(asio::buffer(buf), ec);
            if (ec == asio::error::would_block || ec == asio::error::try_again) continue;
            if (ec) throw Error(ec == asio::error::eof ? "server closed the control connection" : "control channel: " + ec.message());
            rx_.insert(rx_.end(), buf, buf + got);
        }
    }

private:
    std::vector<uint8_t> rx_;
};

std::string default_cache_dir() {
    if (const char* x = std::getenv("XDG_CACHE_HOME"); x && *x) return std::string(x) + "/progskin";
    if (const char* h = std::getenv("HOME"); h && *h) return std::string(h) + "/.cache/progskin";
    return "/tmp/progskin-cache";
}

std::vector<uint8_t> read_file(const fs::path& p) {
    std::ifstream f(p, std::ios::binary);
    if (!f) return {};
    return {std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>()};
}

const wire::Control* expect(std::vector<uint8_t>& body) {
    const wire::Control* c = verify_control(body);
    if (!c) throw Error("server sent a malformed control message");
    return c;
}

// Downloads (or finds in the cache) one asset file; returns its path.
std::string fetch_asset(ControlChannel& ctl, const wire::Asset* a, const std::string& cache_dir, ClientReport& rep,
                        double timeout, const std::function<void(const std::string&, uint64_t, uint64_t)>& progress) {
    std::string name = a->name() ? a->name()->str() : "asset.glb";
    std::string ext = fs::path(name).extension().string();
    if (ext != ".glb" && ext != ".gltf") ext = ".glb";
    fs::create_directories(cache_dir);
    fs::path path = fs::path(cache_dir) / (hex64(a->asset_id()) + ext);
    if (fs::exists(path)) {
        auto bytes = read_file(path);
        if (content_hash(bytes) == a->asset_id()) {
            ++rep.assets_cached;
            return path.string();
        }
    }
    const uint64_t size = a->size();
    if (size == 0 || size > (1ull << 31)) throw Error("server announced asset " + name + " of " + std::to_string(size) + " bytes");
    std::vector<uint8_t> bytes(size);
    uint64_t requested = 0, received = 0;
    int in_flight = 0;
    std::vector<uint8_t> body;
    while (received < size) {
        while (in_flight < 4 && requested < size) {
            flatbuffers::FlatBufferBuilder fbb;
            uint32_t len = uint32_t(std::min<uint64_t>(MAX_ASSET_CHUNK, size - requested));
            auto r = wire::CreateAssetRequest(fbb, a->asset_id(), requested, len);
            fbb.Finish(wire::CreateControl(fbb, wire::ControlBody::AssetRequest, r.Union()), wire::ControlIdentifier());
            ctl.send(fbb);
            requested += len;
            ++in_flight;
        }
        if (!ctl.next(body, timeout)) throw Error("timed out downloading " + name);
        const wire::Control* c = expect(body);
        if (c->body_type() == wire::ControlBody::Goodbye)
            throw Error("server said goodbye during download: " + (c->body_as_Goodbye()->reason() ? c->body_as_Goodbye()->reason()->str() : ""));
        if (c->body_type() != wire::ControlBody::AssetChunk) continue;
        const wire::AssetChunk* ch = c->body_as_AssetChunk();
        if (ch->asset_id() != a->asset_id() || !ch->data() || ch->offset() >= size || ch->offset() + ch->data()->size() > size)
            throw Error("server sent a bad asset chunk");
        std::copy(ch->data()->begin(), ch->data()->end(), bytes.begin() + long(ch->offset()));
        received += ch->data()->size();
        rep.asset_bytes_downloaded += ch->data()->size();
        --in_flight;
        if (progress) progress(name, received, size);
    }
    if (content_hash(bytes) != a->asset_id()) throw Error("downloaded " + name + " does not match its content hash");
    // A temporary name unique to this process and thread: several clients may
    // fill the same cache at once, and the rename makes the file appear whole.
    fs::path tmp = path;
    tmp += ".part" + std::to_string(::getpid()) + "-" +
           std::to_string(std::hash<std::thread::id>{}(std::this_thread::get_id()));
    {
        std::ofstream f(tmp, std::ios::binary);
        f.write(reinterpret_cast<const char*>(bytes.data()), std::streamsize(bytes.size()));
        if (!f) throw Error("cannot write " + tmp.string());
    }
    fs::rename(tmp, path);
    return path.string();
}

std::shared_ptr<ClientAsset> load_client_asset(const wire::Asset* a, const std::string& path) {
    auto ca = std::make_shared<ClientAsset>();
    ca->id = a->asset_id();
    ca->name = a->name() ? a->name()->str() : "";
    ca->path = path;
    ca->character = import_character(path);
    const int B = a->bone_count();
    if (!a->order() || !a->parents() || int(a->order()->size()) != B || int(a->parents()->size()) != B || B < 1 ||
        B > MAX_BONES || (a->corrections() && a->corrections()->size() != size_t(B) * 12))
        throw Error("server sent an inconsistent skin for " + ca->name);
    ProgressiveSkin& s = ca->skin;
    s.order.assign(a->order()->begin(), a->order()->end());
    s.parents.assign(a->parents()->begin(), a->parents()->end());
    if (s.parents[0] != -1) throw Error("bad progressive parents for " + ca->name);
    for (int b = 1; b < B; ++b)
        if (s.parents[b] < 0 || s.parents[b] >= b) throw Error("bad progressive parents for " + ca->name);
    s.corrections.assign(B, Mat34::identity());
    if (a->corrections())
        for (int b = 0; b < B; ++b)
            for (int i = 0; i < 12; ++i) s.corrections[b].m[i] = a->corrections()->Get(size_t(b) * 12 + i);
    if (a->error())
        for (size_t k = 0; k < a->error()->size(); ++k) {
            LodError e;
            e.bones = int(k) + 1;
            e.rms = a->error()->Get(k)->rms();
            e.max = a->error()->Get(k)->max();
            s.error.push_back(e);
        }
    remap_skin_vertices(*ca);
    s.diagonal = a->diagonal();
    ca->diagonal = rest_diagonal(ca->character);
    if (!(ca->diagonal > 0)) ca->diagonal = a->diagonal() > 0 ? a->diagonal() : 1.0;
    if (a->t_min()) ca->format.t_min = {a->t_min()->x(), a->t_min()->y(), a->t_min()->z()};
    if (a->t_max()) ca->format.t_max = {a->t_max()->x(), a->t_max()->y(), a->t_max()->z()};
    ca->format.scaled = a->scaled();
    return ca;
}

udp::endpoint resolve_udp(asio::io_context& io, const std::string& host, uint16_t port) {
    udp::resolver r(io);
    asio::error_code ec;
    auto res = r.resolve(udp::v4(), host, std::to_string(port), ec);
    if (ec || res.empty()) throw Error("cannot resolve " + host + ": " + ec.message());
    return *res.begin();
}

// Receives one datagram with the kernel's arrival time (SO_TIMESTAMPNS), so
// the per-second rate bins reflect the wire even when this thread is late.
// Returns -1 when nothing is pending; t is on the now_seconds() clock.
ssize_t receive_stamped(udp::socket& s, uint8_t* buf, size_t cap, udp::endpoint& from, double& t) {
    sockaddr_storage addr{};
    iovec iov{buf, cap};
    alignas(cmsghdr) char control[128];
    msghdr msg{};
    msg.msg_name = &addr;
    msg.msg_namelen = sizeof addr;
    msg.msg_iov = &iov;
    msg.msg_iovlen = 1;
    msg.msg_control = control;
    msg.msg_controllen = sizeof control;
    ssize_t n = ::recvmsg(s.native_handle(), &msg, MSG_DONTWAIT);
    if (n < 0) return -1;
    t = now_seconds();
    for (cmsghdr* c = CMSG_FIRSTHDR(&msg); c; c = CMSG_NXTHDR(&msg, c)) {
        if (c->cmsg_level == SOL_SOCKET && c->cmsg_type == SCM_TIMESTAMPNS) {
            timespec ts;
            std::memcpy(&ts, CMSG_DATA(c), sizeof ts);
            timespec rt;
            ::clock_gettime(CLOCK_REALTIME, &rt);
            double age = double(rt.tv_sec - ts.tv_sec) + 1e-9 * double(rt.tv_nsec - ts.tv_nsec);
            if (age > 0 && age < 5.0) t -= age;
        }
    }
    if (addr.ss_family == AF_INET) {
        const auto* in = reinterpret_cast<const sockaddr_in*>(&addr);
        from = udp::endpoint(asio::ip::address_v4(ntohl(in->sin_addr.s_addr)), ntohs(in->sin_port));
    }
    if (msg.msg_flags & MSG_TRUNC) return ssize_t(cap);  // cap > MAX_DATAGRAM: dropped as malformed
    return n;
}

}  // namespace

ClientReport run_client(const ClientOptions& opt) {
    ClientReport rep;
    asio::io_context io;
    ControlChannel ctl(io);
    {
        tcp::resolver r(io);
        asio::error_code ec;
        auto res = r.resolve(opt.host, std::to_string(opt.port), ec);
        if (ec) throw Error("cannot resolve " + opt.host + ": " + ec.message());
        asio::connect(ctl.sock, res, ec);
        if (ec) throw Error("cannot connect to " + opt.host + ":" + std::to_string(opt.port) + ": " + ec.message());
        ctl.sock.set_option(tcp::no_delay(true), ec);
    }
    // Hello
    {
        flatbuffers::FlatBufferBuilder fbb;
        auto name = fbb.CreateString(opt.name.substr(0, MAX_NAME));
        auto token = fbb.CreateString(opt.token.substr(0, MAX_TOKEN));
        auto h = wire::CreateHello(fbb, opt.protocol_version ? opt.protocol_version : PROTOCOL_VERSION, name, token,
                                   uint32_t(std::max(0.0, opt.max_kbps)));
        fbb.Finish(wire::CreateControl(fbb, wire::ControlBody::Hello, h.Union()), wire::ControlIdentifier());
        ctl.send(fbb);
    }
    std::vector<uint8_t> welcome_buf;
    if (!ctl.next(welcome_buf, opt.connect_timeout)) throw Error("no answer from the server");
    const wire::Control* wc = expect(welcome_buf);
    if (wc->body_type() == wire::ControlBody::Refuse) {
        const wire::Refuse* r = wc->body_as_Refuse();
        throw Error("server refused the connection: " + (r->reason() ? r->reason()->str() : std::string("no reason")));
    }
    if (wc->body_type() != wire::ControlBody::Welcome) throw Error("server did not send Welcome");
    const wire::Welcome* w = wc->body_as_Welcome();
    if (w->version() != PROTOCOL_VERSION) throw Error("server speaks protocol version " + std::to_string(w->version()));
    const double tick_rate = w->tick_rate();
    if (!(tick_rate > 0 && tick_rate <= 1000)) throw Error("server sent a bad tick rate");
    const uint64_t session = w->session_id(), token = w->udp_token();

    // Assets
    const std::string cache = opt.cache_dir.empty() ? default_cache_dir() : opt.cache_dir;
    std::vector<std::shared_ptr<ClientAsset>> assets;
    if (w->assets())
        for (const wire::Asset* a : *w->assets()) {
            std::string path = fetch_asset(ctl, a, cache, rep, opt.connect_timeout, opt.on_download);
            assets.push_back(load_client_asset(a, path));
        }
    std::vector<std::unique_ptr<InstanceView>> views;
    std::map<int, int> view_of_instance;
    std::vector<int> instance_ids;
    std::vector<glm::vec3> instance_positions;
    if (w->instances())
        for (const wire::Instance* in : *w->instances()) {
            if (in->asset() >= assets.size()) throw Error("server sent an instance of an unknown asset");
            const auto& ca = assets[in->asset()];
            ClipInfo ci;
            if (in->clips())
                for (int c : *in->clips()) {
                    if (c < 0 || size_t(c) >= ca->character.clips.size()) throw Error("server sent an unknown clip index");
                    ci.selection.clips.push_back(c);
                }
            ci.selection.start = in->clip_start();
            ci.selection.end = in->clip_end();
            ci.time_offset = in->time_offset();
            ci.speed = in->speed();
            view_of_instance[in->id()] = int(views.size());
            instance_ids.push_back(in->id());
            instance_positions.push_back(in->position() ? glm::vec3(in->position()->x(), in->position()->y(), in->position()->z())
                                                        : glm::vec3(0.0f));
            views.push_back(std::make_unique<InstanceView>(ca, ci, opt.blend_frames));
        }

    auto send_view = [&](double cap) {
        flatbuffers::FlatBufferBuilder fbb;
        std::vector<wire::InstanceWeight> ws;
        for (const auto& [i, wt] : opt.view.weights) ws.emplace_back(uint16_t(i), wt);
        auto vw = fbb.CreateVectorOfStructs(ws);
        wire::Vec3 cam(opt.view.camera.x, opt.view.camera.y, opt.view.camera.z);
        wire::ViewBuilder vb(fbb);
        if (opt.view.has_camera) vb.add_camera(&cam);
        vb.add_fov_y(opt.view.fov_y);
        vb.add_viewport_height(opt.view.viewport_height);
        vb.add_weights(vw);
        vb.add_max_kbps(uint32_t(std::max(0.0, cap)));
        auto v = vb.Finish();
        fbb.Finish(wire::CreateControl(fbb, wire::ControlBody::View, v.Union()), wire::ControlIdentifier());
        ctl.send(fbb);
    };
    if (opt.send_view) send_view(0);

    // UDP
    udp::socket us(io);
    us.open(udp::v4());
    us.bind(udp::endpoint(udp::v4(), 0));
    us.non_blocking(true);
    asio::error_code ig;
    us.set_option(asio::socket_base::receive_buffer_size(4 << 20), ig);
    {
        int on = 1;
        ::setsockopt(us.native_handle(), SOL_SOCKET, SO_TIMESTAMPNS, &on, sizeof on);
    }
    udp::endpoint server_udp = opt.udp_via_host.empty()
                                   ? resolve_udp(io, opt.host, w->udp_port())
                                   : resolve_udp(io, opt.udp_via_host, opt.udp_via_port);
    auto send_bind = [&] {
        flatbuffers::FlatBufferBuilder fbb;
        std::vector<uint8_t> pad(64, 0);  // a Bind is always larger than its BindAck
        auto p = fbb.CreateVector(pad);
        auto b = wire::CreateBind(fbb, session, token, p);
        fbb.Finish(wire::CreateDatagram(fbb, 0, now_us32(), wire::DatagramBody::Bind, b.Union()), wire::DatagramIdentifier());
        us.send_to(asio::buffer(fbb.GetBufferPointer(), fbb.GetSize()), server_udp, 0, ig);
    };

    // Receive state
    alignas(16) static thread_local uint8_t buf[2048];
    bool bound = false, any_frame = false;
    uint32_t ack = 0, ack_bits = 0, min_seq = 0, max_seq = 0;
    uint32_t ack_echo = 0;
    double ack_arrival = 0;
    uint64_t unique = 0, since_ack = 0;
    double t_first = 0, tick_offset = -1e300;
    std::vector<double> bins;
    const double t_start = now_seconds();
    double next_bind = 0, last_ack_sent = 0, next_stats = t_start + 1.0;
    double next_display = 0;
    size_t cap_index = 0;
    // Display delay: at least --delay-ms, raised to cover the gaps between an
    // instance's frames (plus their lateness) so the display interpolates
    // rather than holds; it changes by at most 25% of the elapsed time (the
    // display clock runs at 0.75x..1.25x while it adapts), up to max_delay.
    const double base_delay = opt.delay_ms / 1000.0 * tick_rate;
    const double max_delay = std::max(base_delay, opt.max_delay_ms / 1000.0 * tick_rate);
    double delay_ticks = base_delay, needed_delay = 0, last_display_time = 0;
    double end_time = t_start + opt.duration + 5.0;  // fixed once streaming starts
    bool ended_by_server = false;

    // Display statistics
    struct Acc {
        double k_sum = 0, sq = 0, n = 0, max = 0, jump = 0;
        int k_min = 1 << 30, k_max = 0;
        uint64_t frames = 0;
        std::vector<glm::vec3> prev_err;
        bool has_prev = false;
    };
    std::vector<Acc> acc(views.size());
    double all_sq = 0, all_n = 0, all_max = 0;
    std::vector<glm::vec3> shown, ref;
    uint64_t display_count = 0;
    double next_snapshot = 0;

    auto handle_frame = [&](const wire::Datagram* d, size_t n, double t) {
        const wire::Frame* f = d->body_as_Frame();
        const uint32_t seq = d->seq();
        // duplicate?
        bool dup = false;
        if (any_frame) {
            int32_t diff = int32_t(seq - ack);
            if (diff == 0) dup = true;
            else if (diff < 0 && diff >= -32 && (ack_bits & (1u << (-diff - 1)))) dup = true;
        }
        if (dup) {
            ++rep.duplicates;
            return;
        }
        // Every chunk is checked before any is applied (proto/frame_reader.h).
        auto record_size = [&](uint16_t instance) {
            auto it = view_of_instance.find(instance);
            return it == view_of_instance.end() ? 0 : views[it->second]->asset().format.size();
        };
        auto apply = [&](uint16_t instance, int first, int count, int show, const uint8_t* rec) {
            InstanceView& v = *views[view_of_instance[instance]];
            const bool had = !v.buffer().empty();
            const uint32_t prev = v.buffer().newest_tick();
            if (!v.buffer().add_chunk(f->tick(), first, count, show, rec, show)) {
                ++rep.malformed;
            } else if (had && tick_offset > -1e299) {
                // Cover the gap since the instance's newest frame and the gap
                // since these bones' previous frames (deep bones are refreshed
                // less often, scheduler.h).
                double since = int32_t(f->tick() - prev) > 0 ? double(prev) : double(f->tick());
                if (v.buffer().last_gap() > 0) since = std::min(since, double(f->tick()) - v.buffer().last_gap());
                if (since < double(f->tick())) needed_delay = std::max(needed_delay, t * tick_rate + tick_offset - since);
            }
        };
        if (!read_frame(*f, record_size, apply)) {
            ++rep.malformed;
            return;
        }
        // Ack state
        if (!any_frame) {
            ack = seq;
            ack_bits = 0;
            min_seq = max_seq = seq;
            t_first = t;
        } else if (int32_t(seq - ack) > 0) {
            uint32_t shift = seq - ack;
            uint32_t nb = shift >= 32 ? 0 : (ack_bits << shift);
            if (shift <= 32) nb |= 1u << (shift - 1);
            ack_bits = nb;
            ack = seq;
        } else {
            uint32_t back = ack - seq - 1;
            if (back < 32) ack_bits |= 1u << back;
        }
        if (int32_t(seq - max_seq) > 0) max_seq = seq;
        if (int32_t(min_seq - seq) > 0) min_seq = seq;
        if (seq == ack) {
            ack_echo = d->send_time_us();
            ack_arrival = t;
        }
        any_frame = true;
        ++unique;
        ++since_ack;
        ++rep.datagrams;
        size_t bin = size_t((t - t_first));
        if (bins.size() <= bin) bins.resize(bin + 1, 0.0);
        bins[bin] += double(n + UDP_IP_OVERHEAD);
        tick_offset = std::max(tick_offset, double(f->tick()) - t * tick_rate);
    };

    std::vector<uint8_t> body;
    for (;;) {
        double now = now_seconds();
        if (any_frame && now >= end_time) break;
        if (!any_frame && now - t_start > opt.connect_timeout) throw Error("no frames received from the server's UDP port");
        if (!bound && !any_frame && now >= next_bind) {
            send_bind();
            next_bind = now + 0.2;
        }
        // Wait for UDP or TCP or the next display frame.
        double wake = std::min(now + 0.01, next_display > 0 ? next_display : now + 0.01);
        pollfd p[2] = {{us.native_handle(), POLLIN, 0}, {ctl.sock.native_handle(), POLLIN, 0}};
        ::poll(p, 2, std::max(0, int((wake - now) * 1000)));
        // UDP
        for (;;) {
            udp::endpoint from;
            double t = 0;
            const ssize_t got = receive_stamped(us, buf, sizeof buf, from, t);
            if (got < 0) break;
            const size_t n = size_t(got);
            const wire::Datagram* d = verify_datagram({buf, n});
            if (!d || from != server_udp) {
                ++rep.malformed;
                continue;
            }
            if (d->body_type() == wire::DatagramBody::BindAck) {
                bound = true;
                continue;
            }
            if (d->body_type() != wire::DatagramBody::Frame) {
                ++rep.malformed;
                continue;
            }
            bool first = !any_frame;
            handle_frame(d, n, t);
            if (first && any_frame) {
                end_time = t + opt.duration;
                next_display = t;
            }
        }
        // TCP
        if (p[1].revents) {
            while (ctl.next(body, 0)) {
                const wire::Control* c = expect(body);
                if (c->body_type() == wire::ControlBody::Stats) {
                    rep.rtt_ms = c->body_as_Stats()->rtt_ms();
                    rep.estimate_kbps = c->body_as_Stats()->estimate_kbps();
                } else if (c->body_type() == wire::ControlBody::Goodbye) {
                    ended_by_server = true;
                    break;
                }
            }
            if (ended_by_server) break;
        }
        now = now_seconds();
        // Acks
        if (any_frame && since_ack > 0 && (since_ack >= 8 || now - last_ack_sent > 0.033)) {
            flatbuffers::FlatBufferBuilder fbb;
            uint32_t hold = uint32_t(std::max(0.0, (now - ack_arrival) * 1e6));
            auto a = wire::CreateAck(fbb, session, token, ack, ack_bits, ack_echo, hold);
            fbb.Finish(wire::CreateDatagram(fbb, 0, now_us32(), wire::DatagramBody::Ack, a.Union()), wire::DatagramIdentifier());
            us.send_to(asio::buffer(fbb.GetBufferPointer(), fbb.GetSize()), server_udp, 0, ig);
            since_ack = 0;
            last_ack_sent = now;
        }
        // Stats every second, cap schedule
        if (now >= next_stats) {
            flatbuffers::FlatBufferBuilder fbb;
            wire::StatsBuilder sb(fbb);
            sb.add_rate_kbps(float(bins.size() >= 2 ? bins[bins.size() - 2] * 8 / 1000 : 0));
            auto s = sb.Finish();
            fbb.Finish(wire::CreateControl(fbb, wire::ControlBody::Stats, s.Union()), wire::ControlIdentifier());
            ctl.send(fbb);
            next_stats = now + 1.0;
        }
        if (any_frame && cap_index < opt.cap_schedule.size() && now - t_first >= opt.cap_schedule[cap_index].first) {
            send_view(opt.cap_schedule[cap_index].second);
            ++cap_index;
        }
        // Display
        if (any_frame && next_display > 0 && now >= next_display) {
            next_display += 1.0 / opt.display_rate;
            if (next_display < now) next_display = now + 1.0 / opt.display_rate;
            {
                const double elapsed = last_display_time > 0 ? (now - last_display_time) * tick_rate : 0;
                last_display_time = now;
                const double target = std::clamp(needed_delay + 0.5, base_delay, max_delay);
                const double step = 0.25 * elapsed;
                delay_ticks += std::clamp(target - delay_ticks, -step, step);
                needed_delay *= std::pow(0.7, elapsed / tick_rate);  // forget over a few seconds
                rep.delay_ms = std::max(rep.delay_ms, delay_ticks / tick_rate * 1000.0);
            }
            double d = now * tick_rate + tick_offset - delay_ticks;
            if (opt.snap_to_ticks) d = std::floor(d);
            const bool verify_now = opt.verify && (display_count % size_t(std::max(1, opt.verify_every)) == 0);
            ++display_count;
            const bool warm = now - t_first >= opt.warmup;
            for (size_t i = 0; i < views.size(); ++i) {
                InstanceView& v = *views[i];
                if (!v.buffer().covers(d) || !v.display(d)) continue;  // nothing that old received yet
                if (!warm) continue;  // the display delay is still adapting
                Acc& a = acc[i];
                int k = v.target_bones();
                a.k_sum += k;
                a.k_min = std::min(a.k_min, k);
                a.k_max = std::max(a.k_max, k);
                ++a.frames;
                if (!verify_now || v.clip().selection.clips.empty()) continue;
                v.skin(shown);
                v.reference(v.clip().clip_time(d, tick_rate), ref);
                const double scale = 100.0 / v.asset().diagonal;
                double jump = 0;
                if (a.prev_err.size() != shown.size()) a.prev_err.assign(shown.size(), glm::vec3(0.0f));
                for (size_t j = 0; j < shown.size(); ++j) {
                    glm::vec3 e = shown[j] - ref[j];
                    double pct = glm::length(e) * scale;
                    a.sq += pct * pct;
                    a.max = std::max(a.max, pct);
                    if (a.has_prev) jump = std::max(jump, double(glm::length(e - a.prev_err[j])) * scale);
                    a.prev_err[j] = e;
                }
                a.n += double(shown.size());
                a.has_prev = opt.verify_every <= 1;
                a.jump = std::max(a.jump, jump);
            }
            if (opt.on_snapshot && opt.snapshot_every > 0 && warm && now >= next_snapshot) {
                next_snapshot = now + opt.snapshot_every;
                DisplaySnapshot snap;
                snap.seconds = now - t_first;
                snap.rate_kbps = bins.size() >= 2 ? bins[bins.size() - 2] * 8.0 / 1000.0 : 0.0;
                for (size_t i = 0; i < views.size(); ++i) {
                    const InstanceView& v = *views[i];
                    if (acc[i].frames == 0) continue;  // nothing displayed yet
                    snap.characters.push_back({instance_ids[i], &v.asset().character, &v.asset().skin, &v.asset().stream, v.palette(),
                                               instance_positions[i], v.target_bones()});
                }
                if (!snap.characters.empty()) opt.on_snapshot(snap);
            }
            if (opt.verbose && bins.size() >= 2 && display_count % size_t(opt.display_rate) == 0)
                std::fprintf(stderr, "progskin-client: %.1f s, %.1f kbit/s last second, %llu datagrams\n", now - t_first,
                             bins[bins.size() - 2] * 8 / 1000, (unsigned long long)rep.datagrams);
        }
    }
    // Goodbye
    if (!ended_by_server) {
        flatbuffers::FlatBufferBuilder fbb;
        build_goodbye(fbb, "done");
        try {
            ctl.send(fbb);
        } catch (const Error&) {
        }
    }
    const double t_end = now_seconds();
    rep.seconds = any_frame ? t_end - t_first : 0;
    double total = 0;
    for (size_t i = 0; i < bins.size(); ++i) {
        total += bins[i];
        if (i + 1 < bins.size() && double(i + 1) <= rep.seconds) {  // full one-second bins
            rep.per_second_kbps.push_back(bins[i] * 8 / 1000);
            rep.rate_max_kbps = std::max(rep.rate_max_kbps, bins[i] * 8 / 1000);
        }
    }
    rep.rate_kbps = rep.seconds > 0 ? total * 8 / 1000 / rep.seconds : 0;
    uint64_t span = any_frame ? uint64_t(max_seq - min_seq) + 1 : 0;
    rep.loss = span ? std::max(0.0, 1.0 - double(unique) / double(span)) : 0;
    double kmin = 1e9, kmax = 0, ksum = 0;
    int counted = 0;
    for (size_t i = 0; i < views.size(); ++i) {
        const Acc& a = acc[i];
        InstanceReport ir;
        ir.instance = int(i);
        ir.asset = views[i]->asset().name;
        ir.frames = a.frames;
        if (a.frames) {
            ir.bones_mean = a.k_sum / double(a.frames);
            ir.bones_min = a.k_min;
            ir.bones_max = a.k_max;
            ++counted;
            ksum += ir.bones_mean;
            kmin = std::min(kmin, ir.bones_mean);
            kmax = std::max(kmax, ir.bones_mean);
        }
        if (a.n > 0) {
            ir.rms_pct = std::sqrt(a.sq / a.n);
            ir.max_pct = a.max;
            ir.max_jump_pct = a.jump;
            all_sq += a.sq;
            all_n += a.n;
            all_max = std::max(all_max, a.max);
            rep.max_jump_pct = std::max(rep.max_jump_pct, a.jump);
        }
        rep.instances.push_back(ir);
    }
    rep.characters = 0;  // instances with at least one frame received
    for (const auto& v : views) rep.characters += v->buffer().empty() ? 0 : 1;
    rep.bones_mean = counted ? ksum / counted : 0;
    rep.bones_min = counted ? kmin : 0;
    rep.bones_max = counted ? kmax : 0;
    if (all_n > 0) {
        rep.rms_pct = std::sqrt(all_sq / all_n);
        rep.max_pct = all_max;
    }
    return rep;
}

std::string report_json(const ClientReport& r) {
    std::ostringstream o;
    o.precision(6);
    o << "{\"seconds\": " << r.seconds << ", \"rate_kbps\": " << r.rate_kbps << ", \"datagrams\": " << r.datagrams
      << ", \"loss\": " << r.loss << ", \"characters\": " << r.characters << ", \"bones_mean\": " << r.bones_mean
      << ", \"bones_min\": " << r.bones_min << ", \"bones_max\": " << r.bones_max << ", \"rms_pct\": ";
    if (r.rms_pct >= 0) o << r.rms_pct; else o << "null";
    o << ", \"max_pct\": ";
    if (r.max_pct >= 0) o << r.max_pct; else o << "null";
    o << ", \"rate_max_kbps\": " << r.rate_max_kbps << ", \"max_jump_pct\": " << r.max_jump_pct
      << ", \"delay_ms_max\": " << r.delay_ms << ", \"rtt_ms\": " << r.rtt_ms << ", \"estimate_kbps\": " << r.estimate_kbps << ", \"malformed\": " << r.malformed
      << ", \"duplicates\": " << r.duplicates << ", \"asset_bytes_downloaded\": " << r.asset_bytes_downloaded
      << ", \"assets_cached\": " << r.assets_cached << ", \"per_second_kbps\": [";
    for (size_t i = 0; i < r.per_second_kbps.size(); ++i) o << (i ? ", " : "") << r.per_second_kbps[i];
    o << "], \"instances\": [";
    for (size_t i = 0; i < r.instances.size(); ++i) {
        const auto& x = r.instances[i];
        o << (i ? ", " : "") << "{\"instance\": " << x.instance << ", \"asset\": \"" << x.asset << "\", \"bones_mean\": " << x.bones_mean
          << ", \"bones_min\": " << x.bones_min << ", \"bones_max\": " << x.bones_max << ", \"rms_pct\": " << x.rms_pct
          << ", \"max_pct\": " << x.max_pct << ", \"max_jump_pct\": " << x.max_jump_pct << ", \"frames\": " << x.frames << "}";
    }
    o << "]}";
    return o.str();
}

std::string report_text(const ClientReport& r) {
    char b[512];
    std::snprintf(b, sizeof b,
                  "%.1f s: %.1f kbit/s (max %.1f over 1 s), %llu datagrams, loss %.1f%%, %d characters, bones mean %.1f "
                  "(min %.1f, max %.1f)",
                  r.seconds, r.rate_kbps, r.rate_max_kbps, (unsigned long long)r.datagrams, 100 * r.loss, r.characters,
                  r.bones_mean, r.bones_min, r.bones_max);
    std::string s = b;
    if (r.rms_pct >= 0) {
        std::snprintf(b, sizeof b, ", error RMS %.4f%% max %.4f%% of diagonal", r.rms_pct, r.max_pct);
        s += b;
    }
    return s + "\n";
}

}  // namespace progskin::net
