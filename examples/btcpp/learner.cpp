// A BehaviorTree.CPP robot that learns through a KT-BT agent running beside it.
//
//   ktbt peer run --id robot --export-learned learned/ --sequence 'TargetSeen(colour=2)' ...
//   learner examples/btcpp/control.xml learned/ --target 2
//
// The robot ticks control.xml (what `ktbt convert examples/btcpp/control.sbt` writes). The agent
// writes each item it learns into the folder as its own BehaviorTree.CPP document and removes
// it when the item is forgotten (spec/stringbt.md, section 12.1): the numbered files, which this
// robot places (an item under a tree ID given with --tree-id is <ID>.xml instead, for a tree
// that names it as a <SubTree>: section 12.3, navigate_with_learned.xml). BehaviorTree.CPP
// cannot edit a running tree, so at the first tick boundary after every change of the folder
// the robot builds its tree again, with each learned item, in the order of their numbers, as a
// <SubTree> at the end of its placeholder <ReactiveFallback name="k:NAME"> (found with
// tinyxml2, whatever the control tree's layout), then halts the old tree and runs the new one.
// A file it cannot load is refused (printed) and left out; the rest of the tree is built
// without it. A port value that does not read fails its node.
//
// Its nodes are the search-and-rescue robot's (compiled in below) and, for a robot with its own
// node names, every other condition and action that the <TreeNodesModel> of its control
// document declares, each registered as a scripted leaf with the ports the model gives it
// (int, double and bool ports are read as such, any other as text):
//
//   ktbt convert door_control.sbt door_control.xml   # the model declares every leaf it uses
//   ktbt peer run --vocabulary door.toml --control door_control.sbt --export-learned learned/ ...
//   learner door_control.xml learned/ --true DoorClosed --true 'HandleSeen side=left'
//
// A scripted action prints its call and succeeds; a scripted condition holds when a --true
// names it, alone or with its ports as an action's call prints them (so `HandleSeen side=left`
// holds and `HandleSeen side=right` does not). The model is the robot's, read once: a learned
// file naming a node the model does not declare is refused like any node the robot lacks (a
// learned file's own <TreeNodesModel> adds nothing). Add a leaf the control tree does not use
// to its model by hand.
//
// Options: --target C (the colour the robot sees, 0 for none), --true CALL (repeated),
// --ticks N (0: until stopped), --period-ms P (between ticks). It prints "rebuilt N learned",
// "refused FILE: WHY", "failure NODE: WHY" (a port that did not read), each call of an action
// ("call NAME port=value ..."; RandomWalk only when it starts) and each halt.
#include <algorithm>
#include <chrono>
#include <csignal>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <regex>
#include <set>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "behaviortree_cpp/action_node.h"
#include "behaviortree_cpp/bt_factory.h"
#include "behaviortree_cpp/condition_node.h"
#include "ktbt_btcpp.hpp"
#include "scripted.hpp"
#include "tinyxml2/tinyxml2.h"  // BehaviorTree.CPP's own parser, which its library exports

namespace fs = std::filesystem;

namespace
{

volatile std::sig_atomic_t stopping = 0;
int seen_target = 0;  // the colour in view
bool carrying = false;
std::set<std::string> holding;  // the --true calls: the scripted conditions that hold

using ktbt_scripted::Leaf;
using ktbt_scripted::say;
std::vector<Leaf> modelled;  // the control document's leaves, read once in main()

/// A port that does not read as an int (a peer's `colour="red"`, `colour=3000000000`) fails
/// the node, and says why; it never ends the program.
bool colourOf(BT::TreeNode& node, int& colour)
{
  auto read = node.getInput<int>("colour");
  if(!read)
  {
    say("failure " + node.registrationName() + ": " + read.error());
    return false;
  }
  colour = read.value();
  return true;
}

BT::NodeStatus targetSeen(BT::TreeNode& node)
{
  int colour = 0;
  if(!colourOf(node, colour))
  {
    return BT::NodeStatus::FAILURE;
  }
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
  int colour = 0;
  if(!colourOf(node, colour))
  {
    return BT::NodeStatus::FAILURE;
  }
  say("call AssignCollectionPoint colour=" + std::to_string(colour));
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
  ktbt_scripted::registerScripted(factory, modelled, holding);
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
  static const std::regex learned("[0-9]{6,}-[A-Za-z_][A-Za-z0-9_]*(\\.[A-Za-z_][A-Za-z0-9_]*)*"
                                  "-[0-9a-f]{16}\\.xml");
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

/// A learned item: its file, its placeholder (from the file name) and its document.
struct Item
{
  std::string file, slot, text, id;
};

/// The placeholder <ReactiveFallback name="k:SLOT"> under `element`, or null.
tinyxml2::XMLElement* placeholder(tinyxml2::XMLElement* element, const std::string& name)
{
  for(auto* child = element->FirstChildElement(); child; child = child->NextSiblingElement())
  {
    const char* attribute = child->Attribute("name");
    if(std::string(child->Name()) == "ReactiveFallback" && attribute && name == attribute)
    {
      return child;
    }
    if(auto* found = placeholder(child, name))
    {
      return found;
    }
  }
  return nullptr;
}

/// The control tree with each item as `<SubTree ID=... _autoremap="true"/>` at the end of its
/// placeholder (replacing an empty placeholder's <AlwaysFailure/>), parsed and written with
/// tinyxml2, the XML parser BehaviorTree.CPP itself uses.
std::string placed(const std::string& base_xml, const std::vector<Item>& items)
{
  tinyxml2::XMLDocument doc;
  if(doc.Parse(base_xml.c_str(), base_xml.size()) != tinyxml2::XML_SUCCESS)
  {
    throw std::runtime_error(std::string("control tree: ") + doc.ErrorStr());
  }
  auto* root = doc.RootElement();
  for(const Item& item : items)
  {
    auto* slot = root ? placeholder(root, "k:" + item.slot) : nullptr;
    if(slot == nullptr)
    {
      throw std::runtime_error("the tree has no placeholder k:" + item.slot);
    }
    auto* only = slot->FirstChildElement();
    if(only && std::string(only->Name()) == "AlwaysFailure" && !only->NextSiblingElement())
    {
      slot->DeleteChild(only);
    }
    auto* ref = doc.NewElement("SubTree");
    ref->SetAttribute("ID", item.id.c_str());
    ref->SetAttribute("_autoremap", "true");
    slot->InsertEndChild(ref);
  }
  tinyxml2::XMLPrinter out;
  doc.Print(&out);
  return out.CStr();
}

/// Reads a learned file: its one <BehaviorTree ID=...>, and the placeholder its name gives.
Item readItem(const fs::path& folder, const std::string& name)
{
  Item item{ name, name.substr(name.find('-') + 1, name.rfind('-') - name.find('-') - 1),
             readFile(folder / name), "" };
  tinyxml2::XMLDocument doc;
  if(doc.Parse(item.text.c_str(), item.text.size()) != tinyxml2::XML_SUCCESS)
  {
    throw std::runtime_error(doc.ErrorStr());
  }
  const auto* root = doc.RootElement();
  const auto* tree = root ? root->FirstChildElement("BehaviorTree") : nullptr;
  if(tree == nullptr || tree->Attribute("ID") == nullptr)
  {
    throw std::runtime_error("no <BehaviorTree ID=...>");
  }
  item.id = tree->Attribute("ID");
  return item;
}

/// The control tree with `items` in its placeholders, built by a factory of its own.
BT::Tree create(const std::string& base_xml, const std::vector<Item>& items)
{
  BT::BehaviorTreeFactory factory;
  registerRobot(factory);
  for(const Item& item : items)
  {
    factory.registerBehaviorTreeFromText(item.text);
  }
  factory.registerBehaviorTreeFromText(placed(base_xml, items));
  return factory.createTree("MainTree");
}

/// Numbers first by their width, then as text: 999999 before 1000000.
bool numbered(const std::string& a, const std::string& b)
{
  return std::make_pair(a.find('-'), a) < std::make_pair(b.find('-'), b);
}

/// The tree with every learned file in the folder that it can load, in the order of their
/// numbers: each candidate (the items kept so far and that file) is built whole, as the robot
/// would run it, and a file whose build throws (a node, a port or a value it does not have, a
/// placeholder the tree lacks) is refused and left out. Nothing running is touched here.
BT::Tree build(const std::string& base_xml, const fs::path& folder, const Listing& files,
               std::size_t& kept)
{
  std::vector<std::string> names;
  for(const auto& entry : files)
  {
    names.push_back(entry.first);
  }
  std::sort(names.begin(), names.end(), numbered);
  std::vector<Item> items;
  BT::Tree tree = create(base_xml, items);
  for(const auto& name : names)
  {
    try
    {
      std::vector<Item> candidate = items;
      candidate.push_back(readItem(folder, name));
      tree = create(base_xml, candidate);
      items = std::move(candidate);
    }
    catch(const std::exception& err)
    {
      say("refused " + name + ": " + err.what());
    }
  }
  kept = items.size();
  return tree;
}

}  // namespace

int main(int argc, char** argv)
{
  const char* usage = "usage: learner CONTROL.xml LEARNED_DIR [--target C] [--true CALL]... "
                      "[--ticks N] [--period-ms P]\n";
  if(argc < 3)
  {
    std::cerr << usage;
    return 2;
  }
  const fs::path control = argv[1], folder = argv[2];
  long ticks = 0, period_ms = 10;
  for(int i = 3; i < argc; i += 2)
  {
    const std::string option = argv[i];
    if(i + 1 == argc)
    {
      std::cerr << "error: " << option << ": needs a value\n" << usage;
      return 2;
    }
    const std::string value = argv[i + 1];
    if(option == "--true")
    {
      holding.insert(value);
      continue;
    }
    long number = 0;
    try
    {
      std::size_t read = 0;
      number = std::stol(value, &read);
      if(read != value.size())
        throw std::invalid_argument(value);
    }
    catch(const std::exception&)
    {
      std::cerr << "error: " << option << ": not a whole number: " << value << "\n";
      return 2;
    }
    if(option == "--target")
      seen_target = int(number);
    else if(option == "--ticks")
      ticks = number;
    else if(option == "--period-ms")
      period_ms = number;
    else
    {
      std::cerr << "error: " << option << ": no such option\n" << usage;
      return 2;
    }
  }
  std::signal(SIGTERM, [](int) { stopping = 1; });
  std::signal(SIGINT, [](int) { stopping = 1; });
  try
  {
    const std::string base = readFile(control);
    modelled = ktbt_scripted::readModel(base);
    Listing files = listing(folder);
    std::size_t kept = 0;
    BT::Tree tree = build(base, folder, files, kept);
    say("rebuilt " + std::to_string(kept) + " learned");
    for(long tick = 1; !stopping && (ticks == 0 || tick <= ticks); ++tick)
    {
      // A tick boundary: the tree is between two ticks, so rebuilding cuts no tick in half.
      // Every change of the folder rebuilds, whatever runs (spec/stringbt.md, section 12.1).
      Listing now = listing(folder);
      if(now != files)
      {
        files = std::move(now);
        BT::Tree next = build(base, folder, files, kept);  // the old tree still runs meanwhile
        tree.haltTree();
        tree = std::move(next);
        say("rebuilt " + std::to_string(kept) + " learned");
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
