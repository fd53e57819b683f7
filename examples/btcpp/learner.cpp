// A BehaviorTree.CPP robot that learns through a KT-BT agent running beside it.
//
//   ktbt peer run --id robot --export-learned learned/ --sequence 'TargetSeen(colour=2)' ...
//   learner examples/btcpp/control.xml learned/ --target 2
//
// The robot ticks control.xml (what `ktbt convert examples/btcpp/control.sbt` writes). The agent
// writes each item it learns into the folder as its own BehaviorTree.CPP document and removes
// it when the item is forgotten (spec/stringbt.md, section 12.1). BehaviorTree.CPP cannot edit
// a running tree, so at a tick boundary after the folder changed the robot halts its tree and
// builds it again, with each learned item, in file-name order, as a <SubTree> at the end of its
// placeholder <ReactiveFallback name="k:NAME">. A file it cannot load is refused (printed) and
// left out; the rest of the tree is built without it.
//
// Options: --target C (the colour the robot sees, 0 for none), --ticks N (0: until stopped),
// --period-ms P (between ticks). It prints "rebuilt N learned", "refused FILE: WHY", each call
// of an action ("call NAME port=value"; RandomWalk only when it starts) and each halt.
#include <algorithm>
#include <chrono>
#include <csignal>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <regex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "behaviortree_cpp/action_node.h"
#include "behaviortree_cpp/bt_factory.h"
#include "behaviortree_cpp/condition_node.h"
#include "ktbt_btcpp.hpp"

namespace fs = std::filesystem;

namespace
{

volatile std::sig_atomic_t stopping = 0;
int seen_target = 0;  // the colour in view
bool carrying = false;

void say(const std::string& line)
{
  std::cout << line << std::endl;  // one flushed line each: a watcher reads them as they come
}

BT::NodeStatus targetSeen(BT::TreeNode& node)
{
  const int colour = node.getInput<int>("colour").value();
  return colour == seen_target ? BT::NodeStatus::SUCCESS : BT::NodeStatus::FAILURE;
}

BT::NodeStatus pickTreasure(BT::TreeNode&)
{
  say("call PickTreasure");
  carrying = true;
  return BT::NodeStatus::SUCCESS;
}

BT::NodeStatus assignCollectionPoint(BT::TreeNode& node)
{
  say("call AssignCollectionPoint colour=" +
      std::to_string(node.getInput<int>("colour").value()));
  return BT::NodeStatus::SUCCESS;
}

BT::NodeStatus deliverToZone(BT::TreeNode&)
{
  say("call DeliverToZone");
  carrying = false;
  return BT::NodeStatus::SUCCESS;
}

class RandomWalk : public BT::StatefulActionNode
{
public:
  RandomWalk(const std::string& name, const BT::NodeConfig& config)
    : BT::StatefulActionNode(name, config)
  {}
  static BT::PortsList providedPorts()
  {
    return {};
  }
  BT::NodeStatus onStart() override
  {
    say("call RandomWalk");
    return BT::NodeStatus::RUNNING;
  }
  BT::NodeStatus onRunning() override
  {
    return BT::NodeStatus::RUNNING;
  }
  void onHalted() override
  {
    say("halt RandomWalk");
  }
};

/// The robot's own nodes, and KT-BT's: what learned knowledge may use.
void registerRobot(BT::BehaviorTreeFactory& factory)
{
  ktbt::registerNodes(factory);
  factory.registerSimpleCondition("Carrying", [](BT::TreeNode&) {
    return carrying ? BT::NodeStatus::SUCCESS : BT::NodeStatus::FAILURE;
  });
  factory.registerSimpleCondition("TargetSeen", targetSeen, { BT::InputPort<int>("colour") });
  factory.registerSimpleAction("PickTreasure", pickTreasure);
  factory.registerSimpleAction("AssignCollectionPoint", assignCollectionPoint,
                               { BT::InputPort<int>("colour") });
  factory.registerSimpleAction("DeliverToZone", deliverToZone);
  factory.registerNodeType<RandomWalk>("RandomWalk");
}

std::string readFile(const fs::path& path)
{
  std::ifstream in(path, std::ios::binary);
  std::ostringstream text;
  text << in.rdbuf();
  return text.str();
}

/// What the folder holds now: learned files by name, with their size and time of change.
using Listing = std::map<std::string, std::pair<std::uintmax_t, fs::file_time_type>>;

Listing listing(const fs::path& folder)
{
  static const std::regex learned("[0-9]{6}-[A-Za-z_][A-Za-z0-9_.]*-[0-9a-f]{16}\\.xml");
  Listing out;
  std::error_code error;
  for(const auto& entry : fs::directory_iterator(folder, error))
  {
    const std::string name = entry.path().filename().string();
    if(std::regex_match(name, learned))
    {
      out[name] = { entry.file_size(error), entry.last_write_time(error) };
    }
  }
  return out;
}

/// Inserts `<SubTree ID=.../>` at the end of placeholder `slot` in `base`; false if the base
/// has no such placeholder. An empty placeholder's <AlwaysFailure/> is replaced.
bool place(std::string& base, const std::string& slot, const std::string& id)
{
  const std::string open = "<ReactiveFallback name=\"k:" + slot + "\">";
  const auto at = base.find(open);
  if(at == std::string::npos)
  {
    return false;
  }
  const auto body = at + open.size();
  // The placeholder's own closing tag: innate items may nest reactive fallbacks of their own.
  std::size_t end = body;
  for(int depth = 1; depth > 0;)
  {
    const auto opening = base.find("<ReactiveFallback", end);
    const auto closing = base.find("</ReactiveFallback>", end);
    if(closing == std::string::npos)
    {
      return false;
    }
    if(opening < closing)
    {
      ++depth;
      end = opening + 1;
    }
    else
    {
      --depth;
      end = depth > 0 ? closing + 1 : closing;
    }
  }
  const std::string ref = "<SubTree ID=\"" + id + "\" _autoremap=\"true\"/>";
  std::string inner = base.substr(body, end - body);
  inner.erase(0, inner.find_first_not_of(" \t\r\n"));
  inner.erase(inner.find_last_not_of(" \t\r\n") + 1);
  if(inner == "<AlwaysFailure/>")
  {
    base.replace(body, end - body, ref);
  }
  else
  {
    base.insert(end, ref);
  }
  return true;
}

BT::Tree build(const std::string& base_xml, const fs::path& folder, const Listing& files)
{
  BT::BehaviorTreeFactory factory;
  registerRobot(factory);
  std::string main_xml = base_xml;
  static const std::regex tree_id("<BehaviorTree ID=\"([^\"]+)\"");
  int placed = 0;
  for(const auto& [name, info] : files)
  {
    const std::string slot =
        name.substr(7, name.size() - 7 - std::string("-0123456789abcdef.xml").size());
    try
    {
      const std::string text = readFile(folder / name);
      std::smatch id;
      if(!std::regex_search(text, id, tree_id))
      {
        throw std::runtime_error("no <BehaviorTree ID=...>");
      }
      std::string candidate = main_xml;
      if(!place(candidate, slot, id[1]))
      {
        throw std::runtime_error("the tree has no placeholder k:" + slot);
      }
      factory.registerBehaviorTreeFromText(text);
      main_xml = candidate;
      ++placed;
    }
    catch(const std::exception& err)
    {
      say("refused " + name + ": " + err.what());
    }
  }
  factory.registerBehaviorTreeFromText(main_xml);
  say("rebuilt " + std::to_string(placed) + " learned");
  return factory.createTree("MainTree");
}

}  // namespace

int main(int argc, char** argv)
{
  if(argc < 3)
  {
    std::cerr << "usage: learner CONTROL.xml LEARNED_DIR [--target C] [--ticks N] "
                 "[--period-ms P]\n";
    return 2;
  }
  const fs::path control = argv[1], folder = argv[2];
  long ticks = 0, period_ms = 10;
  for(int i = 3; i + 1 < argc; i += 2)
  {
    const std::string option = argv[i];
    const long value = std::stol(argv[i + 1]);
    if(option == "--target")
      seen_target = int(value);
    else if(option == "--ticks")
      ticks = value;
    else if(option == "--period-ms")
      period_ms = value;
  }
  std::signal(SIGTERM, [](int) { stopping = 1; });
  std::signal(SIGINT, [](int) { stopping = 1; });
  try
  {
    const std::string base = readFile(control);
    Listing files = listing(folder);
    BT::Tree tree = build(base, folder, files);
    for(long tick = 1; !stopping && (ticks == 0 || tick <= ticks); ++tick)
    {
      // A tick boundary: the tree is between two ticks, so rebuilding cuts no tick in half.
      Listing now = listing(folder);
      if(now != files)
      {
        tree.haltTree();
        files = std::move(now);
        tree = build(base, folder, files);
      }
      tree.tickExactlyOnce();
      std::this_thread::sleep_for(std::chrono::milliseconds(period_ms));
    }
    tree.haltTree();
  }
  catch(const std::exception& err)
  {
    say(std::string("error ") + err.what());
    return 2;
  }
  return 0;
}
