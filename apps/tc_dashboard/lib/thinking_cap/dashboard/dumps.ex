defmodule ThinkingCap.Dashboard.Dumps do
  @moduledoc """
  The black box's dumps as the dashboard shows them: the list of a
  robot's dump files (`ThinkingCap.BlackBox.dumps/2`), one found by its
  name for a download (`ThinkingCap.BlackBox.dump_file/3`: a name, never
  a path), and a dump asked for now.

  The dashboard sees the black boxes of its own node: those the ADFs
  started here keep their robots (the dashboard starts with them). A
  dump asked for goes through the blackboard, as the console's does
  (`{:black_box_request, robot, %{reason:, by:, at:}}`); the black box
  announces the file once written (`{:black_box_dump, robot, _}`, a
  telemetry stream of the page). The page downloads a dump from
  `/dumps/ROBOT/NAME` (`ThinkingCap.Dashboard.Core.Download`).
  """

  alias ThinkingCap.{BlackBox, Blackboard}
  alias ThinkingCap.Tuples
  require Tuples

  # the most dumps a list holds (a page is no file manager)
  @most 200

  @typedoc "A dump as the page lists it: its file name, time (ms since the epoch), reason, size."
  @type entry :: %{
          name: String.t(),
          time: integer() | nil,
          reason: String.t(),
          bytes: non_neg_integer(),
          url: String.t()
        }

  @doc """
  The dumps of `robot`, newest first (the #{@most} newest), how many
  there are, and whether it has a black box on this node.
  """
  @spec list(atom()) :: %{dumps: [entry()], total: non_neg_integer(), keeping: boolean()}
  def list(robot) when is_atom(robot) do
    all = BlackBox.dumps(robot)

    dumps =
      for d <- Enum.take(all, @most) do
        name = Path.basename(d.path)

        %{
          name: name,
          time: d.time && DateTime.to_unix(d.time, :millisecond),
          reason: d.reason,
          bytes: d.bytes,
          url: url(robot, name)
        }
      end

    %{dumps: dumps, total: length(all), keeping: BlackBox.ring_buffer(robot) != nil}
  end

  @doc "The dump of `robot` named `name`, or why not (see `ThinkingCap.BlackBox.dump_file/3`)."
  @spec file(atom(), term()) :: {:ok, BlackBox.dump_file()} | {:error, String.t()}
  def file(robot, name) when is_atom(robot), do: BlackBox.dump_file(robot, name)

  @doc """
  Asks the black box of `robot` for a dump now, `by` whom (the reason is
  `dashboard`). Refused when it has none on this node.
  """
  @spec request(atom(), term()) :: :ok | {:error, String.t()}
  def request(robot, by) when is_atom(robot) do
    if BlackBox.ring_buffer(robot) do
      payload = %{reason: "dashboard", by: by, at: System.os_time(:millisecond)}
      {tuple, opts} = Tuples.keyed(Tuples.black_box_request(robot, payload))
      Blackboard.out(tuple, opts)
    else
      {:error, no_black_box(robot)}
    end
  end

  @doc false
  # what the page is told when a robot has no black box here
  @spec no_black_box(atom()) :: String.t()
  def no_black_box(robot),
    do:
      "#{robot} has no black box on this node (an ADF's black_box: section, " <>
        "or ThinkingCap.BlackBox.keep/2, starts one)"

  # where the page downloads a dump (the token goes in the query)
  defp url(robot, name), do: "/dumps/#{URI.encode_www_form("#{robot}")}/#{name}"
end
