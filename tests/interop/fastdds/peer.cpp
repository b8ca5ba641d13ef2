// A ROS 2 peer on eProsima Fast DDS (Debian's libfastrtps), speaking to ttball as rmw_fastrtps
// (ROS 2's default middleware) does: topics `rt/<name>`, types `pkg::msg::dds_::Type_` from
// fastddsgen, and services as two topics `rq/<service>Request` / `rr/<service>Reply` framed the
// way rmw_fastrtps frames them: no header in the payload, the client's reply-reader GUID in the
// request's related sample identity, the reply matched by the related sample identity the server
// sets (the request's sequence number).
//
// Usage:
//   fastdds_peer --domain D --namespace /ns --detections DETECTIONS.hex --rate HZ
//                --calls CALLS.txt --out DIR
// DETECTIONS.hex: one BallDetection CDR payload (encapsulation included, as in an MCAP bag) in
// hex per line, published on <ns>/ball/detections at HZ once the node is matched. The states and
// interceptions the node publishes are written as hex payloads to DIR/states.hex and
// DIR/intercepts.hex. CALLS.txt: one call per line, `SERVICE TYPE REQUEST_HEX` (TYPE one of
// PredictTrajectory, PredictRebound, PlanReturn, ListParameters, GetParameters, SetParameters,
// Trigger), made in order; each reply is
// written to DIR/replies.txt as `SERVICE REPLY_HEX`. Last, the node's entry in
// `ros_discovery_info` (rmw_dds_common's ParticipantEntitiesInfo in the layout of the
// distribution the peer was built for) is written to DIR/discovery.txt, `writer GID_HEX` and
// `reader GID_HEX` per line, beside `endpoint GUID_HEX TOPIC` for every DDS endpoint this
// participant discovered. DIR/summary.txt says what happened. Participants use UDPv4 on
// 127.0.0.1 only.

#include <algorithm>
#include <atomic>
#include <chrono>
#include <fstream>
#include <iostream>
#include <map>
#include <memory>
#include <mutex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <fastdds/dds/domain/DomainParticipant.hpp>
#include <fastdds/dds/domain/DomainParticipantFactory.hpp>
#include <fastdds/dds/domain/DomainParticipantListener.hpp>
#include <fastdds/dds/publisher/DataWriter.hpp>
#include <fastdds/dds/publisher/Publisher.hpp>
#include <fastdds/dds/subscriber/DataReader.hpp>
#include <fastdds/dds/subscriber/SampleInfo.hpp>
#include <fastdds/dds/subscriber/Subscriber.hpp>
#include <fastdds/dds/topic/Topic.hpp>
#include <fastdds/dds/topic/TypeSupport.hpp>
#include <fastdds/rtps/transport/UDPv4TransportDescriptor.h>
#include <fastrtps/rtps/common/WriteParams.h>

#include "ttball.h"
#include "ttballPubSubTypes.h"

using namespace eprosima::fastdds::dds;
using eprosima::fastrtps::rtps::SerializedPayload_t;
using eprosima::fastrtps::rtps::WriteParams;
using Clock = std::chrono::steady_clock;

namespace {

std::vector<uint8_t> from_hex(const std::string& hex) {
    std::vector<uint8_t> out;
    for (size_t i = 0; i + 1 < hex.size(); i += 2) {
        out.push_back(static_cast<uint8_t>(std::stoi(hex.substr(i, 2), nullptr, 16)));
    }
    return out;
}

std::string to_hex(const SerializedPayload_t& p) {
    static const char* digits = "0123456789abcdef";
    std::string out;
    for (uint32_t i = 0; i < p.length; ++i) {
        out.push_back(digits[p.data[i] >> 4]);
        out.push_back(digits[p.data[i] & 15]);
    }
    return out;
}

// A sample of the type behind `type`, from a hex CDR payload.
bool decode(TypeSupport& type, const std::string& hex, void* sample) {
    std::vector<uint8_t> bytes = from_hex(hex);
    SerializedPayload_t payload(static_cast<uint32_t>(bytes.size()));
    std::copy(bytes.begin(), bytes.end(), payload.data);
    payload.length = static_cast<uint32_t>(bytes.size());
    return type->deserialize(&payload, sample);
}

std::string encode(TypeSupport& type, void* sample) {
    SerializedPayload_t payload(type->getSerializedSizeProvider(sample)() + 4);
    if (!type->serialize(sample, &payload)) {
        return "";
    }
    return to_hex(payload);
}

std::string bytes_hex(const uint8_t* data, size_t n) {
    static const char* digits = "0123456789abcdef";
    std::string out;
    for (size_t i = 0; i < n; ++i) {
        out.push_back(digits[data[i] >> 4]);
        out.push_back(digits[data[i] & 15]);
    }
    return out;
}

// Every DDS endpoint discovered: its GUID (prefix and entity id, 16 bytes) in hex, and topic.
struct Discovered : public DomainParticipantListener {
    std::mutex lock;
    std::map<std::string, std::string> endpoints;

    void add(const eprosima::fastrtps::rtps::GUID_t& guid, const std::string& topic) {
        std::string hex = bytes_hex(guid.guidPrefix.value, 12) + bytes_hex(guid.entityId.value, 4);
        std::lock_guard<std::mutex> guard(lock);
        endpoints[hex] = topic;
    }

    void on_publisher_discovery(DomainParticipant*,
                                eprosima::fastrtps::rtps::WriterDiscoveryInfo&& info) override {
        add(info.info.guid(), info.info.topicName().to_string());
    }

    void on_subscriber_discovery(DomainParticipant*,
                                 eprosima::fastrtps::rtps::ReaderDiscoveryInfo&& info) override {
        add(info.info.guid(), info.info.topicName().to_string());
    }
};

struct Peer {
    Discovered discovered;
    DomainParticipant* participant = nullptr;
    // Each service's request writer and reply reader, by service name.
    std::map<std::string, std::pair<DataWriter*, DataReader*>> clients;
    Publisher* publisher = nullptr;
    Subscriber* subscriber = nullptr;

    explicit Peer(int domain) {
        DomainParticipantQos qos;
        qos.name("ttball_fastdds_peer");
        qos.transport().use_builtin_transports = false;
        auto udp = std::make_shared<eprosima::fastdds::rtps::UDPv4TransportDescriptor>();
        udp->interfaceWhiteList.push_back("127.0.0.1");
        qos.transport().user_transports.push_back(udp);
        participant =
            DomainParticipantFactory::get_instance()->create_participant(domain, qos, &discovered);
        publisher = participant->create_publisher(PUBLISHER_QOS_DEFAULT);
        subscriber = participant->create_subscriber(SUBSCRIBER_QOS_DEFAULT);
    }

    Topic* topic(const std::string& name, TypeSupport& type) {
        type.register_type(participant);
        TopicDescription* known = participant->lookup_topicdescription(name);
        if (known) {
            return static_cast<Topic*>(known);
        }
        return participant->create_topic(name, type.get_type_name(), TOPIC_QOS_DEFAULT);
    }

    DataWriter* writer(const std::string& name, TypeSupport& type, bool reliable) {
        DataWriterQos qos = DATAWRITER_QOS_DEFAULT;
        qos.reliability().kind = reliable ? RELIABLE_RELIABILITY_QOS : BEST_EFFORT_RELIABILITY_QOS;
        qos.durability().kind = VOLATILE_DURABILITY_QOS;
        qos.history().kind = KEEP_LAST_HISTORY_QOS;
        qos.history().depth = 100;
        return publisher->create_datawriter(topic(name, type), qos);
    }

    DataReader* reader(const std::string& name, TypeSupport& type) {
        DataReaderQos qos = DATAREADER_QOS_DEFAULT;
        qos.reliability().kind = RELIABLE_RELIABILITY_QOS;
        qos.durability().kind = VOLATILE_DURABILITY_QOS;
        qos.history().kind = KEEP_ALL_HISTORY_QOS;
        return subscriber->create_datareader(topic(name, type), qos);
    }
};

bool wait_until(const std::function<bool()>& done, double seconds) {
    auto until = Clock::now() + std::chrono::duration<double>(seconds);
    while (Clock::now() < until) {
        if (done()) {
            return true;
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    return done();
}

// Takes every sample `reader` holds, appending each payload (hex) to `out`.
template <class T>
size_t drain(DataReader* reader, TypeSupport& type, std::ofstream& out) {
    size_t n = 0;
    T sample;
    SampleInfo info;
    while (reader->take_next_sample(&sample, &info) == ReturnCode_t::RETCODE_OK) {
        if (info.valid_data) {
            out << encode(type, &sample) << "\n";
            ++n;
        }
    }
    return n;
}

// One service call as rmw_fastrtps makes it; the reply's payload in hex, or "" on timeout.
template <class Request, class RequestType, class Reply, class ReplyType>
std::string call(Peer& peer, const std::string& service, const std::string& request_hex,
                 std::string& why) {
    TypeSupport request_type(new RequestType());
    TypeSupport reply_type(new ReplyType());
    // One client per service, kept for its next calls, as an rmw client is.
    auto& client = peer.clients[service];
    if (!client.first) {
        client.first = peer.writer("rq" + service + "Request", request_type, true);
        client.second = peer.reader("rr" + service + "Reply", reply_type);
    }
    DataWriter* writer = client.first;
    DataReader* reader = client.second;
    if (!writer || !reader) {
        why = "cannot create the service's writer or reader";
        return "";
    }
    PublicationMatchedStatus pub{};
    SubscriptionMatchedStatus sub{};
    bool matched = wait_until(
        [&] {
            writer->get_publication_matched_status(pub);
            reader->get_subscription_matched_status(sub);
            return pub.current_count > 0 && sub.current_count > 0;
        },
        20.0);
    if (!matched) {
        why = "the service was not matched";
        return "";
    }
    // rmw_fastrtps waits for the reply reader to be matched too; give discovery a moment.
    std::this_thread::sleep_for(std::chrono::milliseconds(300));
    Request request;
    if (!decode(request_type, request_hex, &request)) {
        why = "the request does not decode";
        return "";
    }
    // Replies are volatile: one written before the node's reply writer has matched this reader
    // is lost (the race every DDS service client has). Asked again after 5 s, up to 4 times.
    std::string reply_hex;
    for (int attempt = 0; attempt < 4 && reply_hex.empty(); ++attempt) {
        WriteParams params;
        params.related_sample_identity().writer_guid(reader->guid());
        if (!writer->write(&request, params)) {
            why = "the request was not written";
            return "";
        }
        auto sequence = params.sample_identity().sequence_number();
        wait_until(
            [&] {
                Reply reply;
                SampleInfo info;
                while (reader->take_next_sample(&reply, &info) == ReturnCode_t::RETCODE_OK) {
                    auto related = info.related_sample_identity;
                    if (info.valid_data && related.sequence_number() == sequence &&
                        (related.writer_guid() == reader->guid() ||
                         related.writer_guid() == writer->guid())) {
                        reply_hex = encode(reply_type, &reply);
                        return true;
                    }
                }
                return false;
            },
            5.0);
    }
    if (reply_hex.empty()) {
        why = "no reply matched the request's sample identity";
    }
    return reply_hex;
}

namespace rmw = rmw_dds_common::msg::dds_;

// A reader of ros_discovery_info (transient local: the last sample of each participant), made
// at the start so that it has the node's entry by the end.
DataReader* discovery_reader(Peer& peer) {
    TypeSupport type(new rmw::ParticipantEntitiesInfo_PubSubType());
    DataReaderQos qos = DATAREADER_QOS_DEFAULT;
    qos.reliability().kind = RELIABLE_RELIABILITY_QOS;
    qos.durability().kind = TRANSIENT_LOCAL_DURABILITY_QOS;
    qos.history().kind = KEEP_LAST_HISTORY_QOS;
    qos.history().depth = 100;
    return peer.subscriber->create_datareader(peer.topic("ros_discovery_info", type), qos);
}

// The node `ttball`'s entry in what `reader` holds of ros_discovery_info, its writer and reader
// GIDs written to `path` with every endpoint discovered; whether the entry came within 10 s.
bool read_discovery(Peer& peer, DataReader* reader, const std::string& path) {
    if (!reader) {
        return false;
    }
    std::vector<std::string> lines;
    bool found = wait_until(
        [&] {
            rmw::ParticipantEntitiesInfo_ sample;
            SampleInfo info;
            while (reader->take_next_sample(&sample, &info) == ReturnCode_t::RETCODE_OK) {
                if (!info.valid_data) {
                    continue;
                }
                for (const auto& node : sample.node_entities_info_seq()) {
                    if (std::string(node.node_name().c_str()) != "ttball") {
                        continue;
                    }
                    lines.clear();
                    for (const auto& gid : node.writer_gid_seq()) {
                        lines.push_back("writer " + bytes_hex(gid.data().data(), gid.data().size()));
                    }
                    for (const auto& gid : node.reader_gid_seq()) {
                        lines.push_back("reader " + bytes_hex(gid.data().data(), gid.data().size()));
                    }
                }
            }
            return !lines.empty();
        },
        10.0);
    std::ofstream out(path);
    for (const auto& line : lines) {
        out << line << "\n";
    }
    std::lock_guard<std::mutex> guard(peer.discovered.lock);
    for (const auto& endpoint : peer.discovered.endpoints) {
        out << "endpoint " << endpoint.first << " " << endpoint.second << "\n";
    }
    return found;
}

}  // namespace

int main(int argc, char** argv) {
    std::map<std::string, std::string> args;
    for (int i = 1; i + 1 < argc; i += 2) {
        args[argv[i]] = argv[i + 1];
    }
    const int domain = std::stoi(args["--domain"]);
    const std::string ns = args.count("--namespace") ? args["--namespace"] : "";
    const double rate = args.count("--rate") ? std::stod(args["--rate"]) : 300.0;
    const std::string out = args["--out"];
    std::ofstream summary(out + "/summary.txt");
    Peer peer(domain);
    if (!peer.participant) {
        summary << "error: no participant\n";
        return 1;
    }

    DataReader* discovery = discovery_reader(peer);
    TypeSupport detection_type(new ttball_msgs::msg::dds_::BallDetection_PubSubType());
    TypeSupport state_type(new ttball_msgs::msg::dds_::BallState_PubSubType());
    TypeSupport intercept_type(new ttball_msgs::msg::dds_::InterceptPrediction_PubSubType());
    DataWriter* detections = peer.writer("rt" + ns + "/ball/detections", detection_type, false);
    DataReader* states = peer.reader("rt" + ns + "/ball/state", state_type);
    DataReader* intercepts = peer.reader("rt" + ns + "/ball/intercept", intercept_type);
    PublicationMatchedStatus pub{};
    SubscriptionMatchedStatus a{}, b{};
    bool matched = wait_until(
        [&] {
            detections->get_publication_matched_status(pub);
            states->get_subscription_matched_status(a);
            intercepts->get_subscription_matched_status(b);
            return pub.current_count > 0 && a.current_count > 0 && b.current_count > 0;
        },
        30.0);
    summary << "matched " << (matched ? "yes" : "no") << "\n";
    if (!matched) {
        return 1;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(500));

    std::ofstream state_out(out + "/states.hex");
    std::ofstream intercept_out(out + "/intercepts.hex");
    size_t sent = 0, got_states = 0, got_intercepts = 0;
    std::ifstream input(args["--detections"]);
    auto period = std::chrono::duration<double>(1.0 / rate);
    auto next = Clock::now();
    for (std::string line; std::getline(input, line);) {
        if (line.empty()) {
            continue;
        }
        ttball_msgs::msg::dds_::BallDetection_ detection;
        if (!decode(detection_type, line, &detection)) {
            summary << "error: detection " << sent << " does not decode\n";
            return 1;
        }
        next += std::chrono::duration_cast<Clock::duration>(period);
        std::this_thread::sleep_until(next);
        detections->write(&detection);
        ++sent;
        got_states += drain<ttball_msgs::msg::dds_::BallState_>(states, state_type, state_out);
        got_intercepts +=
            drain<ttball_msgs::msg::dds_::InterceptPrediction_>(intercepts, intercept_type, intercept_out);
    }
    // The last outputs: until two seconds pass without one.
    auto quiet_since = Clock::now();
    while (Clock::now() - quiet_since < std::chrono::seconds(2)) {
        size_t s = drain<ttball_msgs::msg::dds_::BallState_>(states, state_type, state_out);
        size_t i = drain<ttball_msgs::msg::dds_::InterceptPrediction_>(intercepts, intercept_type,
                                                                       intercept_out);
        if (s + i > 0) {
            quiet_since = Clock::now();
        }
        got_states += s;
        got_intercepts += i;
        std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
    summary << "sent " << sent << "\n";

    std::ofstream replies(out + "/replies.txt");
    std::ifstream calls(args["--calls"]);
    for (std::string line; std::getline(calls, line);) {
        std::istringstream fields(line);
        std::string service, type, hex, why;
        fields >> service >> type >> hex;
        std::string reply;
        using namespace ttball_msgs::srv::dds_;
        namespace rcl = rcl_interfaces::srv::dds_;
        if (type == "PredictTrajectory") {
            reply = call<PredictTrajectory_Request_, PredictTrajectory_Request_PubSubType,
                         PredictTrajectory_Response_, PredictTrajectory_Response_PubSubType>(
                peer, service, hex, why);
        } else if (type == "PredictRebound") {
            reply = call<PredictRebound_Request_, PredictRebound_Request_PubSubType,
                         PredictRebound_Response_, PredictRebound_Response_PubSubType>(
                peer, service, hex, why);
        } else if (type == "PlanReturn") {
            reply = call<PlanReturn_Request_, PlanReturn_Request_PubSubType, PlanReturn_Response_,
                         PlanReturn_Response_PubSubType>(peer, service, hex, why);
        } else if (type == "ListParameters") {
            reply = call<rcl::ListParameters_Request_, rcl::ListParameters_Request_PubSubType,
                         rcl::ListParameters_Response_, rcl::ListParameters_Response_PubSubType>(
                peer, service, hex, why);
        } else if (type == "GetParameters") {
            reply = call<rcl::GetParameters_Request_, rcl::GetParameters_Request_PubSubType,
                         rcl::GetParameters_Response_, rcl::GetParameters_Response_PubSubType>(
                peer, service, hex, why);
        } else if (type == "SetParameters") {
            reply = call<rcl::SetParameters_Request_, rcl::SetParameters_Request_PubSubType,
                         rcl::SetParameters_Response_, rcl::SetParameters_Response_PubSubType>(
                peer, service, hex, why);
        } else if (type == "Trigger") {
            namespace std_srvs = std_srvs::srv::dds_;
            reply = call<std_srvs::Trigger_Request_, std_srvs::Trigger_Request_PubSubType,
                         std_srvs::Trigger_Response_, std_srvs::Trigger_Response_PubSubType>(
                peer, service, hex, why);
        } else {
            why = "unknown service type " + type;
        }
        if (reply.empty()) {
            summary << "error: " << service << ": " << why << "\n";
        } else {
            replies << service << " " << reply << "\n";
        }
    }
    summary << "states " << got_states << "\nintercepts " << got_intercepts << "\n";
    summary << "discovery " << (read_discovery(peer, discovery, out + "/discovery.txt") ? "yes" : "no")
            << "\n";
    summary.close();
    DomainParticipantFactory::get_instance()->delete_participant(peer.participant);
    return 0;
}
